//! A film camera's radial distortion from its calibration certificate: the certificate's table
//! of radial distances and displacements turned into the `brown` model's k1, k2, k3.
//!
//! Why: a film block is nadir and near-parallel, and self-calibrating distortion there bends it
//! (James & Robson 2014); the certificate's curve, measured on a goniometer, is the baseline to
//! hold. Certificates give the displacement Δr (µm, positive outwards) of an image point at
//! radial distance r (mm) from the principal point; the model's displacement at the ideal
//! normalised radius ρ = r / f is f·ρ·(k1 ρ² + k2 ρ⁴ + k3 ρ⁶), that is Δr = r (k1 ρ² + k2 ρ⁴ +
//! k3 ρ⁶), linear in the k's: a least-squares fit.

use nalgebra::{DMatrix, DVector};

use crate::FilmError;

/// The certificate's curve fitted by the radial terms, and how closely.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RadialFit {
    /// k1, k2, k3 of the `brown` model (normalised coordinates); the terms the curve's points
    /// could not fix are 0.
    pub k: [f64; 3],
    /// RMS of the curve's displacements about the fit, µm.
    pub rms_um: f64,
}

/// Fits k1, k2, k3 to a certificate's curve, `(r_mm, dr_um)` pairs, for a camera of focal length
/// `focal_mm`: as many terms as the curve has points away from the centre (at most 3). Errors on
/// a non-positive focal length, a non-finite or negative radius, or no point off the centre.
pub fn radial_from_certificate(curve: &[[f64; 2]], focal_mm: f64) -> Result<RadialFit, FilmError> {
    if !(focal_mm > 0.0 && focal_mm.is_finite()) {
        return Err(FilmError::InvalidOption {
            name: "focal_mm",
            value: focal_mm,
            expected: "a positive focal length, mm",
        });
    }
    for &[r, dr] in curve {
        if !(r >= 0.0 && r.is_finite() && dr.is_finite()) {
            return Err(FilmError::InvalidOption {
                name: "distortion_um",
                value: r,
                expected: "pairs [r_mm, dr_um] with r ≥ 0 and finite values",
            });
        }
    }
    let points: Vec<[f64; 2]> = curve.iter().copied().filter(|p| p[0] > 0.0).collect();
    let terms = points.len().min(3);
    if terms == 0 {
        return Err(FilmError::InvalidOption {
            name: "distortion_um",
            value: 0.0,
            expected: "at least one radius above 0 mm",
        });
    }
    // Columns scaled by the largest radius's powers, so the three are of one size.
    let reach = points.iter().map(|p| p[0]).fold(0.0, f64::max) / focal_mm;
    let mut a = DMatrix::<f64>::zeros(points.len(), terms);
    let mut b = DVector::<f64>::zeros(points.len());
    for (i, &[r, dr]) in points.iter().enumerate() {
        let rho2 = (r / focal_mm).powi(2);
        for t in 0..terms {
            a[(i, t)] = r * (rho2 / (reach * reach)).powi(t as i32 + 1);
        }
        b[i] = dr * 1e-3;
    }
    let solved =
        a.clone()
            .svd(true, true)
            .solve(&b, 1e-12)
            .map_err(|_| FilmError::InvalidOption {
                name: "distortion_um",
                value: points.len() as f64,
                expected: "a curve the radial terms can fit",
            })?;
    let mut k = [0.0; 3];
    for t in 0..terms {
        k[t] = solved[t] / (reach * reach).powi(t as i32 + 1);
    }
    let residual = &a * &solved - &b;
    let rms_um = 1e3 * (residual.norm_squared() / points.len() as f64).sqrt();
    if !(k.iter().all(|v| v.is_finite()) && rms_um.is_finite()) {
        return Err(FilmError::InvalidOption {
            name: "distortion_um",
            value: points.len() as f64,
            expected: "a curve the radial terms can fit",
        });
    }
    Ok(RadialFit { k, rms_um })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The certificate's displacement (µm) at `r` mm of a lens with these k's and focal length.
    fn displacement(k: [f64; 3], focal_mm: f64, r: f64) -> f64 {
        let rho2 = (r / focal_mm).powi(2);
        1e3 * r * (k[0] * rho2 + k[1] * rho2 * rho2 + k[2] * rho2 * rho2 * rho2)
    }

    #[test]
    fn a_curve_made_by_the_model_gives_its_terms_back_exactly() {
        let (k, f) = ([-2.1e-3, 4.0e-4, -3.0e-5], 152.06);
        let curve: Vec<[f64; 2]> = (0..=15)
            .map(|i| {
                let r = 10.0 * i as f64;
                [r, displacement(k, f, r)]
            })
            .collect();
        let fit = radial_from_certificate(&curve, f).unwrap();
        for t in 0..3 {
            assert!(
                (fit.k[t] - k[t]).abs() < 1e-9 * k[t].abs().max(1e-6),
                "{:?}",
                fit.k
            );
        }
        assert!(fit.rms_um < 1e-9, "{}", fit.rms_um);
    }

    #[test]
    fn a_rounded_certificate_is_fitted_to_its_rounding() {
        // Certificates print whole micrometres: the fit misses by at most half of one.
        let (k, f) = ([-1.5e-3, 2.0e-4, 0.0], 210.0);
        let curve: Vec<[f64; 2]> = (1..=14)
            .map(|i| {
                let r = 10.0 * i as f64;
                [r, displacement(k, f, r).round()]
            })
            .collect();
        let fit = radial_from_certificate(&curve, f).unwrap();
        assert!(fit.rms_um < 0.5, "{}", fit.rms_um);
        let at = |k: [f64; 3]| displacement(k, f, 140.0);
        assert!((at(fit.k) - at(k)).abs() < 1.0, "{:?}", fit.k);
    }

    #[test]
    fn one_point_fixes_k1_alone_and_bad_curves_are_refused() {
        let fit = radial_from_certificate(&[[0.0, 0.0], [100.0, -4.0]], 150.0).unwrap();
        assert_eq!(fit.k[1], 0.0);
        assert!((displacement(fit.k, 150.0, 100.0) + 4.0).abs() < 1e-9);
        assert!(radial_from_certificate(&[[0.0, 0.0]], 150.0).is_err());
        assert!(radial_from_certificate(&[[-5.0, 1.0]], 150.0).is_err());
        assert!(radial_from_certificate(&[[5.0, f64::NAN]], 150.0).is_err());
        assert!(radial_from_certificate(&[[5.0, 1.0]], 0.0).is_err());
    }
}
