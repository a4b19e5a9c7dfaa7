//! The interior orientation of one scan: the plane transform from frame pixels (the camera's
//! frame, `FilmFrame`) to scan pixels, fitted to the measured marks by least squares —
//! similarity (for the robust search), affine (shift, rotation, two scales and shear: a
//! flatbed scan of shrunk film), or projective (with eight or more marks, for scanners whose
//! platen is not parallel to the sensor).

use nalgebra::{Matrix2, Matrix3, SMatrix, SVector, Vector2};

use crate::FilmError;

/// The family of a [`ScanTransform`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TransformModel {
    /// Rotation, one scale, shift (4 parameters).
    Similarity,
    /// Full 2-D affine (6 parameters).
    Affine,
    /// Plane homography (8 parameters).
    Projective,
}

impl TransformModel {
    /// Fewest marks that determine the transform.
    pub fn min_marks(self) -> usize {
        match self {
            TransformModel::Similarity => 2,
            TransformModel::Affine => 3,
            TransformModel::Projective => 4,
        }
    }

    /// Its name in reports.
    pub fn name(self) -> &'static str {
        match self {
            TransformModel::Similarity => "similarity",
            TransformModel::Affine => "affine",
            TransformModel::Projective => "projective",
        }
    }
}

/// Where every frame pixel lies in one scan (`scan_from_frame`, a homogeneous 3 × 3 matrix
/// whose last row is (0, 0, 1) unless the model is projective).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanTransform {
    model: TransformModel,
    scan_from_frame: Matrix3<f64>,
    frame_from_scan: Matrix3<f64>,
}

impl ScanTransform {
    /// A transform from its matrix; fails when it is not invertible or not finite.
    pub fn from_matrix(
        model: TransformModel,
        scan_from_frame: Matrix3<f64>,
    ) -> Result<ScanTransform, FilmError> {
        let degenerate = |reason: &str| FilmError::Degenerate {
            model: model.name(),
            reason: reason.into(),
        };
        if scan_from_frame.iter().any(|v| !v.is_finite()) {
            return Err(degenerate("a coefficient is not finite"));
        }
        let m = if model == TransformModel::Projective {
            let s = scan_from_frame[(2, 2)];
            if s.abs() < 1e-300 {
                return Err(degenerate("the transform maps the origin to infinity"));
            }
            scan_from_frame / s
        } else {
            let mut m = scan_from_frame;
            m[(2, 0)] = 0.0;
            m[(2, 1)] = 0.0;
            m[(2, 2)] = 1.0;
            m
        };
        let linear = m.fixed_view::<2, 2>(0, 0).into_owned();
        let scale = linear.norm();
        if linear.determinant().abs() <= 1e-12 * scale * scale {
            return Err(degenerate("the transform is singular"));
        }
        let inverse = m
            .try_inverse()
            .ok_or_else(|| degenerate("the transform is singular"))?;
        Ok(ScanTransform {
            model,
            scan_from_frame: m,
            frame_from_scan: inverse,
        })
    }

    /// The family it was fitted as.
    pub fn model(&self) -> TransformModel {
        self.model
    }

    /// The homogeneous matrix taking frame pixels to scan pixels.
    pub fn scan_from_frame_matrix(&self) -> &Matrix3<f64> {
        &self.scan_from_frame
    }

    /// The scan pixel of a frame pixel.
    pub fn scan_from_frame(&self, frame: &Vector2<f64>) -> Vector2<f64> {
        apply(&self.scan_from_frame, frame)
    }

    /// The frame pixel of a scan pixel.
    pub fn frame_from_scan(&self, scan: &Vector2<f64>) -> Vector2<f64> {
        apply(&self.frame_from_scan, scan)
    }

    /// The scales of the scan against the frame at a frame position (singular values of the
    /// local Jacobian, larger first): 1 when the scan has the certificate's pixel size.
    pub fn scales_at(&self, frame: &Vector2<f64>) -> (f64, f64) {
        let m = &self.scan_from_frame;
        let w = m[(2, 0)] * frame.x + m[(2, 1)] * frame.y + m[(2, 2)];
        let p = apply(m, frame);
        let j = Matrix2::new(
            (m[(0, 0)] - p.x * m[(2, 0)]) / w,
            (m[(0, 1)] - p.x * m[(2, 1)]) / w,
            (m[(1, 0)] - p.y * m[(2, 0)]) / w,
            (m[(1, 1)] - p.y * m[(2, 1)]) / w,
        );
        let s = j.singular_values();
        (s[0].max(s[1]), s[0].min(s[1]))
    }

    /// The rotation of the scan against the frame at a frame position, radians (the angle of
    /// the frame's x axis in the scan).
    pub fn rotation_at(&self, frame: &Vector2<f64>) -> f64 {
        let d =
            self.scan_from_frame(&(frame + Vector2::new(1.0, 0.0))) - self.scan_from_frame(frame);
        d.y.atan2(d.x)
    }

    /// The least-squares transform of a family taking `frame[k]` to `scan[k]`.
    pub fn fit(
        model: TransformModel,
        frame: &[Vector2<f64>],
        scan: &[Vector2<f64>],
    ) -> Result<ScanTransform, FilmError> {
        assert_eq!(
            frame.len(),
            scan.len(),
            "one scan position per frame position"
        );
        if frame.len() < model.min_marks() {
            return Err(FilmError::TooFewMarks {
                found: frame.len(),
                needed: model.min_marks(),
                model: model.name(),
            });
        }
        match model {
            TransformModel::Similarity => fit_similarity(frame, scan),
            TransformModel::Affine => fit_affine(frame, scan),
            TransformModel::Projective => fit_projective(frame, scan),
        }
    }
}

fn apply(m: &Matrix3<f64>, p: &Vector2<f64>) -> Vector2<f64> {
    let q = m * p.push(1.0);
    Vector2::new(q.x / q.z, q.y / q.z)
}

fn centroid(points: &[Vector2<f64>]) -> Vector2<f64> {
    points.iter().sum::<Vector2<f64>>() / points.len() as f64
}

fn fit_similarity(
    frame: &[Vector2<f64>],
    scan: &[Vector2<f64>],
) -> Result<ScanTransform, FilmError> {
    let (cf, cs) = (centroid(frame), centroid(scan));
    let (mut a, mut b, mut n) = (0.0, 0.0, 0.0);
    for (f, s) in frame.iter().zip(scan) {
        let (f, s) = (f - cf, s - cs);
        a += f.x * s.x + f.y * s.y;
        b += f.x * s.y - f.y * s.x;
        n += f.norm_squared();
    }
    if n <= 0.0 {
        return Err(FilmError::Degenerate {
            model: "similarity",
            reason: "the marks coincide".into(),
        });
    }
    let (a, b) = (a / n, b / n);
    let linear = Matrix2::new(a, -b, b, a);
    let t = cs - linear * cf;
    let m = Matrix3::new(a, -b, t.x, b, a, t.y, 0.0, 0.0, 1.0);
    ScanTransform::from_matrix(TransformModel::Similarity, m)
}

fn fit_affine(frame: &[Vector2<f64>], scan: &[Vector2<f64>]) -> Result<ScanTransform, FilmError> {
    let (cf, cs) = (centroid(frame), centroid(scan));
    let mut ff = Matrix2::zeros();
    let mut sf = Matrix2::zeros();
    for (f, s) in frame.iter().zip(scan) {
        let (f, s) = (f - cf, s - cs);
        ff += f * f.transpose();
        sf += s * f.transpose();
    }
    let spread = ff.trace();
    if ff.determinant() <= 1e-10 * spread * spread {
        return Err(FilmError::Degenerate {
            model: "affine",
            reason: "the marks are collinear".into(),
        });
    }
    let inverse = ff.try_inverse().ok_or_else(|| FilmError::Degenerate {
        model: "affine",
        reason: "the marks are collinear".into(),
    })?;
    let linear = sf * inverse;
    let mut m = Matrix3::identity();
    m.fixed_view_mut::<2, 2>(0, 0).copy_from(&linear);
    m.fixed_view_mut::<2, 1>(0, 2)
        .copy_from(&(cs - linear * cf));
    ScanTransform::from_matrix(TransformModel::Affine, m)
}

/// Normalised DLT, then Gauss–Newton on the scan-pixel residuals (the DLT minimises an
/// algebraic error, which weighs the marks unevenly).
fn fit_projective(
    frame: &[Vector2<f64>],
    scan: &[Vector2<f64>],
) -> Result<ScanTransform, FilmError> {
    let degenerate = |reason: String| FilmError::Degenerate {
        model: "projective",
        reason,
    };
    let h = timesift_geometry::homography::homography_dlt(frame, scan, None)
        .map_err(|e| degenerate(e.to_string()))?;
    let mut h = h / h[(2, 2)];
    for _ in 0..20 {
        let mut jtj = SMatrix::<f64, 8, 8>::zeros();
        let mut jtr = SVector::<f64, 8>::zeros();
        for (f, s) in frame.iter().zip(scan) {
            let q = h * f.push(1.0);
            let w = q.z;
            let p = Vector2::new(q.x / w, q.y / w);
            let r = s - p;
            let ju = SVector::<f64, 8>::from_row_slice(&[
                f.x / w,
                f.y / w,
                1.0 / w,
                0.0,
                0.0,
                0.0,
                -p.x * f.x / w,
                -p.x * f.y / w,
            ]);
            let jv = SVector::<f64, 8>::from_row_slice(&[
                0.0,
                0.0,
                0.0,
                f.x / w,
                f.y / w,
                1.0 / w,
                -p.y * f.x / w,
                -p.y * f.y / w,
            ]);
            jtj += ju * ju.transpose() + jv * jv.transpose();
            jtr += ju * r.x + jv * r.y;
        }
        let step = jtj
            .cholesky()
            .ok_or_else(|| degenerate("the normal equations are singular".into()))?
            .solve(&jtr);
        for k in 0..8 {
            h[(k / 3, k % 3)] += step[k];
        }
        if step.norm() < 1e-12 * (1.0 + h.norm()) {
            break;
        }
    }
    ScanTransform::from_matrix(TransformModel::Projective, h)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn marks() -> Vec<Vector2<f64>> {
        vec![
            Vector2::new(0.0, 0.0),
            Vector2::new(1000.0, 0.0),
            Vector2::new(2000.0, 0.0),
            Vector2::new(2000.0, 1000.0),
            Vector2::new(2000.0, 2000.0),
            Vector2::new(1000.0, 2000.0),
            Vector2::new(0.0, 2000.0),
            Vector2::new(0.0, 1000.0),
        ]
    }

    fn scan_transform(angle: f64, sx: f64, sy: f64, shear: f64, t: (f64, f64)) -> Matrix3<f64> {
        let (s, c) = angle.sin_cos();
        let r = Matrix2::new(c, -s, s, c) * Matrix2::new(sx, shear, 0.0, sy);
        Matrix3::new(
            r[(0, 0)],
            r[(0, 1)],
            t.0,
            r[(1, 0)],
            r[(1, 1)],
            t.1,
            0.0,
            0.0,
            1.0,
        )
    }

    proptest! {
        #[test]
        fn an_affine_scan_is_recovered_exactly(
            angle in -0.03f64..0.03,
            sx in 0.998f64..1.001,
            sy in 0.998f64..1.001,
            shear in -5e-4f64..5e-4,
            tx in -80.0f64..80.0,
            ty in -80.0f64..80.0,
        ) {
            let truth = scan_transform(angle, sx, sy, shear, (tx, ty));
            let frame = marks();
            let scan: Vec<_> = frame.iter().map(|f| apply(&truth, f)).collect();
            for model in [TransformModel::Affine, TransformModel::Projective] {
                let fit = ScanTransform::fit(model, &frame[..5], &scan[..5]).unwrap();
                for (f, s) in frame.iter().zip(&scan) {
                    prop_assert!((fit.scan_from_frame(f) - s).norm() < 1e-6);
                    prop_assert!((fit.frame_from_scan(s) - f).norm() < 1e-6);
                }
            }
        }

        #[test]
        fn a_homography_is_recovered_from_noisy_marks_within_the_noise(
            g in -2e-6f64..2e-6,
            h in -2e-6f64..2e-6,
            seed in 0u64..1000,
        ) {
            let mut truth = scan_transform(0.01, 1.0, 0.999, 1e-4, (30.0, -20.0));
            truth[(2, 0)] = g;
            truth[(2, 1)] = h;
            let frame = marks();
            let mut rng = timesift_core::SeededRng::new(seed);
            let scan: Vec<_> = frame
                .iter()
                .map(|f| apply(&truth, f) + Vector2::new(rng.normal(), rng.normal()) * 0.05)
                .collect();
            let fit = ScanTransform::fit(TransformModel::Projective, &frame, &scan).unwrap();
            for f in &frame {
                prop_assert!((fit.scan_from_frame(f) - apply(&truth, f)).norm() < 0.2);
            }
        }
    }

    #[test]
    fn similarity_recovers_rotation_and_scale() {
        let truth = scan_transform(0.015, 0.9995, 0.9995, 0.0, (12.5, -7.25));
        let frame = marks();
        let scan: Vec<_> = frame.iter().map(|f| apply(&truth, f)).collect();
        let fit = ScanTransform::fit(TransformModel::Similarity, &frame[..2], &scan[..2]).unwrap();
        assert!((fit.rotation_at(&frame[0]) - 0.015).abs() < 1e-12);
        let (a, b) = fit.scales_at(&frame[3]);
        assert!((a - 0.9995).abs() < 1e-12 && (b - 0.9995).abs() < 1e-12);
    }

    #[test]
    fn degenerate_marks_are_errors_never_nan() {
        let line = [
            Vector2::new(0.0, 0.0),
            Vector2::new(1.0, 1.0),
            Vector2::new(2.0, 2.0),
            Vector2::new(3.0, 3.0),
        ];
        assert!(matches!(
            ScanTransform::fit(TransformModel::Affine, &line, &line),
            Err(FilmError::Degenerate { .. })
        ));
        assert!(ScanTransform::fit(TransformModel::Projective, &line, &line).is_err());
        let same = [Vector2::new(5.0, 5.0); 2];
        assert!(ScanTransform::fit(TransformModel::Similarity, &same, &same).is_err());
        assert!(matches!(
            ScanTransform::fit(TransformModel::Affine, &line[..2], &line[..2]),
            Err(FilmError::TooFewMarks {
                found: 2,
                needed: 3,
                ..
            })
        ));
    }
}
