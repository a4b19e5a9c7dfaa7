//! How well the control of an adjustment fixes the tilt of its datum.
//!
//! Why: a block can tilt as a whole about a horizontal axis by as much as its control lets it.
//! Control points along a corridor and GNSS centres with metres of noise leave the roll about
//! the corridor's axis loose, and check points along that axis cannot see it; the DEM can (a
//! tilt of 1 mm/m is 0.1 m of false change across 100 m). This module predicts that tilt's
//! standard deviation from the control alone, so a report can say what the control supports
//! before anyone reads a DoD.
//!
//! The model treats the block as rigid: every height observation of the datum (a control
//! point's survey, a camera's GNSS height) sees `a + b·x + c·y` plus its noise, where (b, c) is
//! the tilt. GNSS heights of one flight share an offset that the adjustment estimates with a
//! zero-mean prior ([`crate::OffsetPrior`]), so within a flight only their differences fix the
//! tilt. Least squares over (a, b, c, offsets) gives the covariance of (b, c); its larger
//! eigenvalue is the loosest tilt. A control point's σ should hold its markers' intersection
//! error as well as its survey's (the caller combines them): clicked on coarse pixels, that is
//! the larger. The figure ignores what the tie points themselves may bend, so it is a lower
//! bound on the real tilt's σ.

use nalgebra::{DMatrix, DVector, Matrix2, Vector2};

/// One height observation of the datum.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeightObservation {
    /// Horizontal position, metres.
    pub xy: Vector2<f64>,
    /// Standard deviation of the height, metres.
    pub sigma_z: f64,
    /// The estimated offset it carries (index into the `offsets_sigma_z` of [`datum_tilt`]);
    /// `None`: an absolute height (a control point, an unbiased prior).
    pub offset: Option<usize>,
}

/// The predicted tilt of a datum.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DatumTilt {
    /// Standard deviation of the tilt about the loosest axis, mm per m.
    pub sigma_max_mm_per_m: f64,
    /// About the firmest axis, mm per m.
    pub sigma_min_mm_per_m: f64,
    /// Direction of steepest loose tilt (the gradient's direction, perpendicular to the axis it
    /// turns about), degrees counter-clockwise from +x (east).
    pub loose_azimuth_deg: f64,
    /// Standard deviation of the datum's height at the observations' weighted centre, metres:
    /// how far the block as a whole may sit up or down, which no DoD shows but every absolute
    /// height (a DEM against a survey) does. `None` when no observation's height is absolute
    /// (GNSS heights that all carry an estimated offset without a prior).
    pub sigma_height_m: Option<f64>,
}

/// The tilt's covariance from `observations`, each GNSS offset with the prior σ in
/// `offsets_sigma_z` (metres). `None` when they do not fix a tilt: fewer than three
/// independent heights, or all on a line.
pub fn datum_tilt(
    observations: &[HeightObservation],
    offsets_sigma_z: &[f64],
) -> Option<DatumTilt> {
    let usable: Vec<&HeightObservation> = observations
        .iter()
        .filter(|o| {
            o.sigma_z > 0.0
                && o.sigma_z.is_finite()
                && o.xy.iter().all(|v| v.is_finite())
                && o.offset.is_none_or(|k| k < offsets_sigma_z.len())
        })
        .collect();
    if usable.len() < 3 {
        return None;
    }
    // Centred on the weighted mean and scaled to about one, so the normal matrix is well
    // conditioned whatever the block's size and origin, and the tilt is uncorrelated with the
    // datum's height (which the prior below may then touch without touching the tilt).
    let weight = |o: &HeightObservation| 1.0 / (o.sigma_z * o.sigma_z);
    let total: f64 = usable.iter().map(|o| weight(o)).sum();
    let mean = usable
        .iter()
        .fold(Vector2::zeros(), |s, o| s + o.xy * weight(o))
        / total;
    let scale = usable
        .iter()
        .map(|o| (o.xy - mean).norm())
        .fold(0.0, f64::max);
    if !(scale > 0.0) {
        return None;
    }
    let unknowns = 3 + offsets_sigma_z.len();
    let mut normal = DMatrix::<f64>::zeros(unknowns, unknowns);
    let mut row = DVector::<f64>::zeros(unknowns);
    for o in &usable {
        let p = (o.xy - mean) / scale;
        row.fill(0.0);
        row[0] = 1.0;
        row[1] = p.x;
        row[2] = p.y;
        if let Some(k) = o.offset {
            row[3 + k] = 1.0;
        }
        normal.ger(1.0 / (o.sigma_z * o.sigma_z), &row, &row, 1.0);
    }
    for (k, &sigma) in offsets_sigma_z.iter().enumerate() {
        // A missing or unbounded prior leaves the offset free.
        if sigma > 0.0 && sigma.is_finite() {
            normal[(3 + k, 3 + k)] += 1.0 / (sigma * sigma);
        }
    }
    // Offsets no observation carries and no prior bounds would make the matrix singular
    // without telling anything about the tilt: pin them.
    for k in 0..offsets_sigma_z.len() {
        if normal[(3 + k, 3 + k)] == 0.0 {
            normal[(3 + k, 3 + k)] = 1.0;
        }
    }
    // Without absolute heights, the datum's height and the offsets are one unknown: a prior
    // a billion times weaker than the data separates them. The tilt does not depend on how
    // (their confounded direction has no tilt component), only the matrix needs it.
    // The datum's height is fixed where some height is absolute, or carries an offset that a
    // prior bounds.
    let absolute = usable.iter().any(|o| {
        o.offset
            .is_none_or(|k| offsets_sigma_z[k] > 0.0 && offsets_sigma_z[k].is_finite())
    });
    if usable.iter().all(|o| o.offset.is_some()) {
        normal[(0, 0)] *= 1.0 + 1e-9;
    }
    let covariance = normal.cholesky()?.inverse();
    // Back to metres per metre, then to mm per m.
    let tilt = Matrix2::new(
        covariance[(1, 1)],
        covariance[(1, 2)],
        covariance[(2, 1)],
        covariance[(2, 2)],
    ) / (scale * scale);
    let eigen = tilt.symmetric_eigen();
    let (loose, firm) = if eigen.eigenvalues[0] >= eigen.eigenvalues[1] {
        (0, 1)
    } else {
        (1, 0)
    };
    let (max, min) = (eigen.eigenvalues[loose], eigen.eigenvalues[firm]);
    // A tilt the observations barely see (points nearly on a line) is not a figure.
    if !(min > 0.0) || !(max.is_finite()) || max / min > 1e12 {
        return None;
    }
    let direction = eigen.eigenvectors.column(loose);
    let mut azimuth = direction[1].atan2(direction[0]).to_degrees();
    if azimuth < 0.0 {
        azimuth += 180.0;
    }
    if azimuth >= 180.0 {
        azimuth -= 180.0;
    }
    Some(DatumTilt {
        sigma_max_mm_per_m: 1e3 * max.sqrt(),
        sigma_min_mm_per_m: 1e3 * min.sqrt(),
        loose_azimuth_deg: azimuth,
        sigma_height_m: absolute
            .then(|| covariance[(0, 0)].sqrt())
            .filter(|s| s.is_finite()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn close(a: f64, b: f64, relative: f64) {
        assert!(
            (a - b).abs() <= relative * b.abs().max(1e-12),
            "{a} against {b}"
        );
    }

    fn absolute(x: f64, y: f64, sigma_z: f64) -> HeightObservation {
        HeightObservation {
            xy: Vector2::new(x, y),
            sigma_z,
            offset: None,
        }
    }

    #[test]
    fn a_square_of_control_gives_the_textbook_slope_precision() {
        // z = a + b x + c y over the corners of a 100 m square, σ = 1 cm: Σ(x − x̄)² = 4 · 50²,
        // so σ_b = σ_c = 0.01 / 100 = 0.1 mm/m.
        let points = [
            absolute(0.0, 0.0, 0.01),
            absolute(100.0, 0.0, 0.01),
            absolute(100.0, 100.0, 0.01),
            absolute(0.0, 100.0, 0.01),
        ];
        let tilt = datum_tilt(&points, &[]).expect("tilt");
        close(tilt.sigma_max_mm_per_m, 0.1, 1e-9);
        close(tilt.sigma_min_mm_per_m, 0.1, 1e-9);
        // The height at the centre: the mean of four, σ / 2.
        close(tilt.sigma_height_m.expect("height"), 0.005, 1e-9);
    }

    #[test]
    fn a_narrow_band_of_control_leaves_the_roll_loose() {
        // Control along x over 200 m, 10 m wide: the roll about the x axis (a gradient along
        // y) is 20 times looser than the pitch.
        let points = [
            absolute(0.0, 0.0, 0.01),
            absolute(200.0, 0.0, 0.01),
            absolute(200.0, 10.0, 0.01),
            absolute(0.0, 10.0, 0.01),
        ];
        let tilt = datum_tilt(&points, &[]).expect("tilt");
        close(tilt.sigma_max_mm_per_m, 0.01 / 10.0 * 1e3, 1e-9);
        close(tilt.sigma_min_mm_per_m, 0.01 / 200.0 * 1e3, 1e-9);
        close(tilt.loose_azimuth_deg, 90.0, 1e-6);
    }

    #[test]
    fn a_flight_with_a_free_offset_fixes_the_tilt_but_not_the_height() {
        // GNSS heights with an unbounded offset: the tilt as from the same points taken
        // absolute (differences carry all of it for a plane through them).
        let xy = [
            (0.0, 0.0),
            (60.0, 0.0),
            (60.0, 40.0),
            (0.0, 40.0),
            (30.0, 20.0),
        ];
        let flight: Vec<_> = xy
            .iter()
            .map(|&(x, y)| HeightObservation {
                xy: Vector2::new(x, y),
                sigma_z: 1.0,
                offset: Some(0),
            })
            .collect();
        let absolute_points: Vec<_> = xy.iter().map(|&(x, y)| absolute(x, y, 1.0)).collect();
        let free = datum_tilt(&flight, &[f64::INFINITY]).expect("tilt");
        let fixed = datum_tilt(&absolute_points, &[]).expect("tilt");
        close(free.sigma_max_mm_per_m, fixed.sigma_max_mm_per_m, 1e-6);
        close(free.sigma_min_mm_per_m, fixed.sigma_min_mm_per_m, 1e-6);
        assert_eq!(free.sigma_height_m, None);
        close(
            fixed.sigma_height_m.expect("height"),
            1.0 / 5f64.sqrt(),
            1e-9,
        );
        // A prior on the offset fixes the height: the heights' mean (σ² 1/5) less the offset
        // (σ² 2²).
        let bounded = datum_tilt(&flight, &[2.0]).expect("tilt");
        close(
            bounded.sigma_height_m.expect("height"),
            (0.2f64 + 4.0).sqrt(),
            1e-6,
        );
    }

    #[test]
    fn points_on_a_line_or_too_few_fix_no_tilt() {
        let line: Vec<_> = (0..10)
            .map(|k| absolute(10.0 * k as f64, 5.0 * k as f64, 0.01))
            .collect();
        assert!(datum_tilt(&line, &[]).is_none());
        assert!(datum_tilt(&line[..2], &[]).is_none());
        // Bad inputs are left out, not turned into NaN.
        let mut bad = line[..2].to_vec();
        bad.push(absolute(f64::NAN, 0.0, 0.01));
        bad.push(absolute(0.0, 50.0, 0.0));
        assert!(datum_tilt(&bad, &[]).is_none());
    }

    proptest! {
        /// More control never loosens the datum: adding an observation can only lower both σ.
        #[test]
        fn another_observation_never_loosens_the_tilt(
            points in proptest::collection::vec((0.0..500.0f64, 0.0..500.0f64, 0.005..2.0f64), 4..20),
            extra in (0.0..500.0f64, 0.0..500.0f64, 0.005..2.0f64),
            gnss in proptest::bool::ANY,
        ) {
            let offset = gnss.then_some(0);
            let obs: Vec<_> = points
                .iter()
                .map(|&(x, y, s)| HeightObservation { xy: Vector2::new(x, y), sigma_z: s, offset })
                .collect();
            let Some(before) = datum_tilt(&obs, &[3.0]) else { return Ok(()); };
            let mut more = obs.clone();
            more.push(HeightObservation { xy: Vector2::new(extra.0, extra.1), sigma_z: extra.2, offset });
            let after = datum_tilt(&more, &[3.0]).expect("still fixed");
            prop_assert!(after.sigma_max_mm_per_m <= before.sigma_max_mm_per_m * (1.0 + 1e-9));
            prop_assert!(after.sigma_min_mm_per_m <= before.sigma_min_mm_per_m * (1.0 + 1e-9));
            prop_assert!(before.sigma_min_mm_per_m <= before.sigma_max_mm_per_m);
        }
    }
}
