//! Robust losses ρ(s) of a squared, sigma-normalised residual norm s, with the scale `a` in the
//! residual's units (pixels / sigma): cost = ½ Σ ρ(s). Conventions of Ceres, so costs compare.

/// A robust loss.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Loss {
    /// ρ(s) = s.
    Trivial,
    /// ρ(s) = s for s ≤ a², 2a√s − a² beyond.
    Huber(f64),
    /// ρ(s) = a² log(1 + s/a²).
    Cauchy(f64),
    /// ρ(s) = 2a² (√(1 + s/a²) − 1).
    SoftL1(f64),
}

impl Loss {
    /// Checks that the scale is positive and finite.
    pub fn validate(&self) -> Result<(), crate::BundleError> {
        match *self {
            Loss::Trivial => Ok(()),
            Loss::Huber(a) | Loss::Cauchy(a) | Loss::SoftL1(a) if a > 0.0 && a.is_finite() => {
                Ok(())
            }
            other => Err(crate::BundleError::InvalidProblem(format!(
                "loss {other:?}: the scale must be positive and finite"
            ))),
        }
    }

    /// ρ(s) and ρ'(s).
    pub fn evaluate(&self, s: f64) -> (f64, f64) {
        match *self {
            Loss::Trivial => (s, 1.0),
            Loss::Huber(a) => {
                let b = a * a;
                if s <= b {
                    (s, 1.0)
                } else {
                    let r = s.sqrt();
                    (2.0 * a * r - b, a / r)
                }
            }
            Loss::Cauchy(a) => {
                let b = a * a;
                (b * (1.0 + s / b).ln(), 1.0 / (1.0 + s / b))
            }
            Loss::SoftL1(a) => {
                let b = a * a;
                let t = (1.0 + s / b).sqrt();
                (2.0 * b * (t - 1.0), 1.0 / t)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn derivatives_match_central_differences_and_losses_agree_near_zero() {
        for loss in [
            Loss::Trivial,
            Loss::Huber(1.5),
            Loss::Cauchy(2.0),
            Loss::SoftL1(0.7),
        ] {
            for s in [0.01, 0.5, 1.0, 3.0, 40.0] {
                let h = 1e-6 * s;
                let numeric = (loss.evaluate(s + h).0 - loss.evaluate(s - h).0) / (2.0 * h);
                let (_, d) = loss.evaluate(s);
                assert!(
                    (numeric - d).abs() <= 1e-6 * d.abs().max(1e-3),
                    "{loss:?} at {s}: {d} vs {numeric}"
                );
            }
            // All losses behave like s for small residuals.
            let (r, d) = loss.evaluate(1e-8);
            assert!((r - 1e-8).abs() < 1e-12 && (d - 1.0).abs() < 1e-6);
        }
    }
}
