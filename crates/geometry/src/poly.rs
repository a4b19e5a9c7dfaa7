//! Real roots of low-degree polynomials, robust to vanishing leading coefficients.

/// Real roots of `a x² + b x + c`. Falls back to the linear case when `a` vanishes relative to the
/// other coefficients.
pub fn quadratic_roots(a: f64, b: f64, c: f64) -> Vec<f64> {
    let scale = a.abs().max(b.abs()).max(c.abs());
    if scale == 0.0 || !scale.is_finite() {
        return Vec::new();
    }
    if a.abs() <= 1e-14 * scale {
        return if b.abs() > 1e-14 * scale {
            vec![-c / b]
        } else {
            Vec::new()
        };
    }
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 {
        // Tangent roots lost to round-off are kept.
        if disc > -1e-14 * b * b {
            return vec![-b / (2.0 * a)];
        }
        return Vec::new();
    }
    // Numerically stable form (no cancellation).
    let q = -0.5 * (b + b.signum() * disc.sqrt());
    if q == 0.0 {
        return vec![0.0];
    }
    let (r1, r2) = (q / a, c / q);
    if r1 <= r2 { vec![r1, r2] } else { vec![r2, r1] }
}

/// Real roots of `a x³ + b x² + c x + d`, polished by Newton steps.
pub fn cubic_roots(a: f64, b: f64, c: f64, d: f64) -> Vec<f64> {
    let scale = a.abs().max(b.abs()).max(c.abs()).max(d.abs());
    if scale == 0.0 || !scale.is_finite() {
        return Vec::new();
    }
    if a.abs() <= 1e-14 * scale {
        return quadratic_roots(b, c, d);
    }
    let (b, c, d) = (b / a, c / a, d / a);
    // Depressed cubic t³ + p t + q with x = t - b/3.
    let p = c - b * b / 3.0;
    let q = 2.0 * b * b * b / 27.0 - b * c / 3.0 + d;
    let shift = -b / 3.0;
    let disc = q * q / 4.0 + p * p * p / 27.0;
    let mut roots = if disc > 0.0 {
        let s = disc.sqrt();
        vec![(-q / 2.0 + s).cbrt() + (-q / 2.0 - s).cbrt() + shift]
    } else if p == 0.0 {
        vec![shift]
    } else {
        let m = 2.0 * (-p / 3.0).sqrt();
        let theta = ((3.0 * q / (p * m)).clamp(-1.0, 1.0)).acos() / 3.0;
        (0..3)
            .map(|k| m * (theta - 2.0 * std::f64::consts::PI * k as f64 / 3.0).cos() + shift)
            .collect()
    };
    for r in roots.iter_mut() {
        for _ in 0..3 {
            let f = ((*r + b) * *r + c) * *r + d;
            let df = (3.0 * *r + 2.0 * b) * *r + c;
            if df == 0.0 {
                break;
            }
            let step = f / df;
            if !step.is_finite() {
                break;
            }
            *r -= step;
        }
    }
    roots.sort_by(f64::total_cmp);
    roots
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cubic_with_three_and_one_real_roots() {
        let r = cubic_roots(2.0, -2.0 * 6.0, 2.0 * 11.0, -2.0 * 6.0);
        assert_eq!(r.len(), 3);
        for (a, b) in r.iter().zip([1.0, 2.0, 3.0]) {
            assert!((a - b).abs() < 1e-12);
        }
        let r = cubic_roots(1.0, 0.0, 1.0, -2.0); // (x-1)(x²+x+2)
        assert_eq!(r.len(), 1);
        assert!((r[0] - 1.0).abs() < 1e-12);
        let r = cubic_roots(1e-20, 1.0, -3.0, 2.0);
        assert_eq!(r.len(), 2);
    }

    #[test]
    fn quadratic_is_stable() {
        let r = quadratic_roots(1.0, -1e8, 1.0);
        assert!((r[0] - 1e-8).abs() < 1e-20 && (r[1] - 1e8).abs() < 1e-6);
        assert!(quadratic_roots(1.0, 0.0, 1.0).is_empty());
    }
}
