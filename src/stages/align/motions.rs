//! The epochs' rigid motions as the block's covariance holds them, and the tilt σ of an epoch
//! or of a DoD between two that follows from them.

use super::*;

/// The epochs' rigid motions as the block holds them, from its covariance (6 rows per epoch,
/// rotation first). An epoch held to the reference epoch's surface by height observations
/// (surface ties) is special: the adjustment takes those heights as known, so its covariance
/// is the epoch's motion *relative to that surface*, and the surface moves with the reference
/// epoch. Its motion is then the reference epoch's plus its own relative one (independent).
pub(super) struct EpochMotions<'a> {
    covariance: &'a nalgebra::DMatrix<f64>,
    reference: usize,
    /// Per epoch: held to the reference epoch's surface.
    on_surface: Vec<bool>,
}

impl EpochMotions<'_> {
    pub(super) fn of<'a>(
        block: &'a Georeferenced,
        reference: usize,
        epochs: usize,
    ) -> Option<EpochMotions<'a>> {
        let covariance = block.set_motion_covariance.as_ref()?;
        // Held to a reference DEM, the epochs are held to a fixed surface: their covariance is
        // their own motion.
        let tied = block.diagnostics.surface_heights > 0 && !block.fits_against_dem;
        let on_surface = (0..epochs)
            .map(|e| tied && e != reference && block.surface_fits.iter().any(|f| f.epoch == e))
            .collect();
        Some(EpochMotions {
            covariance,
            reference,
            on_surface,
        })
    }

    /// Tilt covariance (2 × 2, radians²) of `Σ w·motion(set)` as the covariance holds it.
    fn raw(&self, combination: &[(usize, f64)]) -> Option<nalgebra::Matrix2<f64>> {
        let c = self.covariance;
        let mut cov = nalgebra::Matrix2::<f64>::zeros();
        for &(s, ws) in combination {
            for &(t, wt) in combination {
                for r in 0..2 {
                    for q in 0..2 {
                        cov[(r, q)] += ws * wt * *c.get((6 * s + r, 6 * t + q))?;
                    }
                }
            }
        }
        Some(cov)
    }

    /// The tilt σ of epoch `e` against the world.
    pub(super) fn epoch(&self, e: usize) -> Option<DatumTiltReport> {
        let own = self.raw(&[(e, 1.0)])?;
        match self.on_surface.get(e) == Some(&true) {
            true => tilt_report(own + self.raw(&[(self.reference, 1.0)])?),
            false => tilt_report(own),
        }
    }

    /// The tilt σ of the DoD `b − a`.
    pub(super) fn dod(&self, a: usize, b: usize) -> Option<DatumTiltReport> {
        let held = |e: usize| self.on_surface.get(e) == Some(&true);
        let relative = |e: usize| -> Option<nalgebra::Matrix2<f64>> {
            match (e == self.reference, held(e)) {
                (true, _) => Some(nalgebra::Matrix2::zeros()),
                (false, true) => self.raw(&[(e, 1.0)]),
                (false, false) => None,
            }
        };
        match (relative(a), relative(b)) {
            // Both follow the reference surface: only their motions relative to it differ.
            (Some(ca), Some(cb)) => tilt_report(ca + cb),
            _ => tilt_report(self.raw(&[(b, 1.0), (a, -1.0)])?),
        }
    }
}

/// The tilt σ report of a tilt covariance: the horizontal components of a rotation are the
/// surface's slope (radians), their covariance's eigenvalues the loosest and firmest tilt.
fn tilt_report(cov: nalgebra::Matrix2<f64>) -> Option<DatumTiltReport> {
    let eigen = cov.symmetric_eigen();
    let (loose, firm) = match eigen.eigenvalues[0] >= eigen.eigenvalues[1] {
        true => (0, 1),
        false => (1, 0),
    };
    let (max, min) = (eigen.eigenvalues[loose], eigen.eigenvalues[firm]);
    if !(max.is_finite() && min >= -1e-18) {
        return None;
    }
    // A rotation (θx, θy) raises the ground by θx·y − θy·x: its gradient is (−θy, θx).
    let axis = eigen.eigenvectors.column(loose);
    Some(DatumTiltReport {
        sigma_max_mm_per_m: 1000.0 * max.sqrt(),
        sigma_min_mm_per_m: 1000.0 * min.max(0.0).sqrt(),
        loose_azimuth_deg: (axis[0]).atan2(-axis[1]).to_degrees().rem_euclid(180.0),
        sigma_height_m: None,
    })
}
