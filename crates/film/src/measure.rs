//! The interior orientation of one scan from its fiducial marks: each mark searched near where
//! the certificate puts it (a coarse correlation on a reduced scan), the marks' positions made
//! consistent by the best similarity over pairs of them (a wrong peak — a scratch, the data
//! strip — cannot agree with the others), lost marks searched again where that similarity
//! puts them, every mark refined by least-squares matching, then the affine (or, with eight
//! marks or more, projective) transform fitted and the worst mark rejected while it stands
//! out. Marks measured by hand are taken as they are.

use nalgebra::{Matrix2, Vector2};

use crate::FilmError;
use crate::frame::FilmFrame;
use crate::raster::{GreyRaster, ImageView};
use crate::template::{Template, least_squares_match, ncc_search};
use crate::transform::{ScanTransform, TransformModel};

/// How marks are searched and judged.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeasureOptions {
    /// Radius of the search around a mark's nominal position (the frame centred on the scan,
    /// one scan pixel per frame pixel), as a fraction of the scan's longer side.
    pub search_fraction: f64,
    /// Lowest correlation of a mark with the template.
    pub min_correlation: f64,
    /// A mark farther than this from the transform fitted to the others is rejected, scan
    /// pixels.
    pub max_residual_px: f64,
    /// Largest relative difference between the scan's scale and the certificate's pixel size
    /// before the scan is reported as disagreeing with the certificate (film shrinks by a few
    /// 1e-4; a percent means a wrong `pixel_mm` or wrong mark coordinates).
    pub scale_tolerance: f64,
    /// Fit a projective transform when eight marks or more are measured, else affine (the
    /// default: a flatbed scan of shrunk film is affine, and with eight marks a projective fit
    /// bends towards a single bad mark at a corner).
    pub projective_from_eight: bool,
}

impl Default for MeasureOptions {
    fn default() -> Self {
        MeasureOptions {
            search_fraction: 0.12,
            min_correlation: 0.6,
            max_residual_px: 1.5,
            scale_tolerance: 0.01,
            projective_from_eight: false,
        }
    }
}

impl MeasureOptions {
    fn validate(&self) -> Result<(), FilmError> {
        let check = |name: &'static str, v: f64, ok: bool, expected: &'static str| {
            if ok && v.is_finite() {
                Ok(())
            } else {
                Err(FilmError::InvalidOption {
                    name,
                    value: v,
                    expected,
                })
            }
        };
        check(
            "search_fraction",
            self.search_fraction,
            self.search_fraction > 0.0 && self.search_fraction <= 0.5,
            "a fraction in (0, 0.5]",
        )?;
        check(
            "min_correlation",
            self.min_correlation,
            self.min_correlation > 0.0 && self.min_correlation < 1.0,
            "a correlation in (0, 1)",
        )?;
        check(
            "max_residual_px",
            self.max_residual_px,
            self.max_residual_px > 0.0,
            "a positive number of pixels",
        )?;
        check(
            "scale_tolerance",
            self.scale_tolerance,
            self.scale_tolerance > 0.0,
            "a positive fraction",
        )
    }
}

/// What became of one mark in one scan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MarkStatus {
    /// Found and refined, used by the interior orientation.
    Measured,
    /// Measured by hand (given), used as given.
    Given,
    /// Not found: no position correlates with the template well enough.
    NotFound,
    /// Found, but left out: too far from the transform of the other marks.
    Rejected,
}

/// One mark in one scan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MarkMeasurement {
    /// Index of the mark in the frame's marks.
    pub mark: usize,
    /// Its position in the scan, pixels (`None` when not found).
    pub scan_px: Option<Vector2<f64>>,
    /// Its correlation with the template (1 for a mark given by hand).
    pub correlation: f64,
    /// Distance from where the interior orientation puts it, scan pixels.
    pub residual_px: Option<f64>,
    /// What became of it.
    pub status: MarkStatus,
}

/// The interior orientation of one scan.
#[derive(Debug, Clone, PartialEq)]
pub struct ScanOrientation {
    /// Every mark of the frame, in the frame's order.
    pub marks: Vec<MarkMeasurement>,
    /// Frame pixels → scan pixels.
    pub transform: ScanTransform,
    /// RMS of the residuals of the marks used, scan pixels (0 when they determine the
    /// transform exactly).
    pub rms_px: f64,
    /// Scan scale against the certificate's pixel size, larger and smaller (singular values at
    /// the frame's centre).
    pub scales: (f64, f64),
    /// What a person should look at, one line each, naming the mark.
    pub warnings: Vec<String>,
}

/// The interior orientation of `scan` (channel 0 is searched) from the marks of `frame`, found
/// with `template`, and `given` marks measured by hand (mark index, scan pixel), which replace
/// the search for those marks.
pub fn orient_scan(
    scan: &ImageView<'_>,
    frame: &FilmFrame,
    template: &Template,
    given: &[(usize, Vector2<f64>)],
    options: &MeasureOptions,
) -> Result<ScanOrientation, FilmError> {
    options.validate()?;
    let radius = search_radius(scan, frame, template, given, options)?;
    let n_marks = frame.marks().len();
    let search = MarkSearch {
        scan,
        frame,
        template,
        given,
        options,
        frame_px: (0..n_marks).map(|k| frame.mark_px(k)).collect(),
        radius,
        grey: GreyRaster::luminance(scan),
    };
    let (coarse, f) = search.coarse_marks()?;

    // The similarity most marks agree with.
    let tolerance = 3.0 * f;
    let mut warnings = Vec::new();
    let similarity = match search.agreed_similarity(&coarse, tolerance) {
        Some(s) => s,
        None => {
            warnings.push(
                "fewer than two marks agree on where the frame lies: searched around the scan's \
                 centre only"
                    .to_string(),
            );
            search.centred_similarity()?
        }
    };

    // Fine: every mark refined where the similarity puts it.
    let mut marks = search.refine_marks(&coarse, &similarity, tolerance);
    for m in &marks {
        if m.status == MarkStatus::NotFound {
            warnings.push(format!(
                "mark {} not found (correlation {:.2} < {})",
                frame.marks()[m.mark].name,
                m.correlation,
                options.min_correlation
            ));
        }
    }

    // The interior orientation, the worst mark rejected while it stands out.
    let transform = search.fit_rejecting_worst(&mut marks)?;
    let used: Vec<&MarkMeasurement> = marks
        .iter()
        .filter(|m| matches!(m.status, MarkStatus::Measured | MarkStatus::Given))
        .collect();
    let rms_px = (used
        .iter()
        .map(|m| m.residual_px.unwrap_or(0.0).powi(2))
        .sum::<f64>()
        / used.len() as f64)
        .sqrt();
    push_residual_warnings(&marks, frame, options, &mut warnings);
    if transform.model() == TransformModel::Similarity {
        warnings.push(format!(
            "only {} marks: a similarity, without the scan's shear and differential scale",
            used.len()
        ));
    }
    let centre = Vector2::new(0.5 * frame.width() as f64, 0.5 * frame.height() as f64);
    let scales = transform.scales_at(&centre);
    if (scales.0 - 1.0).abs() > options.scale_tolerance
        || (scales.1 - 1.0).abs() > options.scale_tolerance
    {
        warnings.push(format!(
            "the scan's scale is {:.4}–{:.4} × the certificate's: pixel_mm or the fiducial \
             coordinates disagree with the scan",
            scales.1, scales.0
        ));
    }
    Ok(ScanOrientation {
        marks,
        transform,
        rms_px,
        scales,
        warnings,
    })
}

/// The radius of the search around a mark's nominal position, scan pixels, once the scan, the
/// template and the given marks are checked against the frame.
fn search_radius(
    scan: &ImageView<'_>,
    frame: &FilmFrame,
    template: &Template,
    given: &[(usize, Vector2<f64>)],
    options: &MeasureOptions,
) -> Result<f64, FilmError> {
    let (sw, sh) = (scan.width() as f64, scan.height() as f64);
    let (fw, fh) = (frame.width() as f64, frame.height() as f64);
    // Marks at the frame's edges reach half a template beyond it.
    if fw > sw * (1.0 + options.scale_tolerance) || fh > sh * (1.0 + options.scale_tolerance) {
        return Err(FilmError::InvalidScan(format!(
            "the marks span {fw} × {fh} pixels of {} mm but the scan is {sw} × {sh} pixels: \
             pixel_mm or the fiducial coordinates disagree with the scan",
            frame.pixel_mm()
        )));
    }
    let radius = options.search_fraction * sw.max(sh);
    let side = 2.0 * radius;
    if template.width() as f64 > side || template.height() as f64 > side {
        return Err(FilmError::InvalidTemplate(format!(
            "{} × {} pixels is larger than the search window of {side:.0} × {side:.0} pixels",
            template.width(),
            template.height()
        )));
    }
    if let Some((k, _)) = given.iter().find(|(k, _)| *k >= frame.marks().len()) {
        return Err(FilmError::InvalidMarks(format!(
            "a given mark has index {k}, the frame has {} marks",
            frame.marks().len()
        )));
    }
    Ok(radius)
}

/// What the search for one scan's marks reads.
struct MarkSearch<'a> {
    scan: &'a ImageView<'a>,
    frame: &'a FilmFrame,
    template: &'a Template,
    given: &'a [(usize, Vector2<f64>)],
    options: &'a MeasureOptions,
    /// Every mark's position in the frame, pixels.
    frame_px: Vec<Vector2<f64>>,
    /// Radius of the coarse search, scan pixels.
    radius: f64,
    /// The scan's luminance.
    grey: GreyRaster,
}

/// A mark's coarse position in the scan and its correlation; `None` when not found.
type CoarseMark = Option<(Vector2<f64>, f64)>;

impl MarkSearch<'_> {
    /// The position of mark `k` measured by hand, if it was.
    fn given_at(&self, k: usize) -> Option<Vector2<f64>> {
        self.given.iter().find(|(m, _)| *m == k).map(|(_, p)| *p)
    }

    /// Where the frame centred on the scan puts frame pixel `p`.
    fn nominal(&self, p: &Vector2<f64>) -> Vector2<f64> {
        let (sw, sh) = (self.scan.width() as f64, self.scan.height() as f64);
        let (fw, fh) = (self.frame.width() as f64, self.frame.height() as f64);
        p + Vector2::new(0.5 * (sw - fw), 0.5 * (sh - fh))
    }

    /// Every mark's coarse position (given marks as they are), searched around its nominal
    /// position on a reduced scan where the template keeps ten pixels or more; with the
    /// reduction factor.
    fn coarse_marks(&self) -> Result<(Vec<CoarseMark>, f64), FilmError> {
        let (template, radius) = (self.template, self.radius);
        let mut factor = 1;
        while factor < 16
            && template.width().min(template.height()) / (2 * factor) >= 10
            && radius / (2 * factor) as f64 >= 8.0
        {
            factor *= 2;
        }
        let (coarse_scan, coarse_template) = if factor > 1 {
            (self.grey.reduced(factor), template.reduced(factor)?)
        } else {
            (self.grey.clone(), template.clone())
        };
        let f = factor as f64;
        // The reduced template covers whole blocks of the template: its centre lies this far
        // from the full template's centre.
        let reduction_offset = Vector2::new(
            0.5 * (template.width() - coarse_template.width() * factor) as f64,
            0.5 * (template.height() - coarse_template.height() * factor) as f64,
        );
        let coarse = (0..self.frame_px.len())
            .map(|k| {
                if let Some(p) = self.given_at(k) {
                    return Some((p, 1.0));
                }
                let peak = ncc_search(
                    &coarse_scan,
                    &coarse_template,
                    &(self.nominal(&self.frame_px[k]) / f),
                    radius / f,
                )?;
                // At whole pixels a fine mark correlates less than it will once refined.
                (peak.correlation >= 0.5 * self.options.min_correlation)
                    .then(|| (peak.centre * f + reduction_offset, peak.correlation))
            })
            .collect();
        Ok((coarse, f))
    }

    /// The similarity most coarse marks agree with (within `tolerance`), refitted to them;
    /// `None` when fewer than two agree.
    fn agreed_similarity(&self, coarse: &[CoarseMark], tolerance: f64) -> Option<ScanTransform> {
        let frame_px = &self.frame_px;
        let candidates: Vec<usize> = (0..frame_px.len())
            .filter(|&k| coarse[k].is_some())
            .collect();
        let position = |k: usize| coarse[k].map(|c| c.0).unwrap_or_default();
        let s = self.best_pair_similarity(&candidates, &position, tolerance)?;
        let inliers: Vec<usize> = candidates
            .iter()
            .copied()
            .filter(|&k| (s.scan_from_frame(&frame_px[k]) - position(k)).norm() < tolerance)
            .collect();
        let f_in: Vec<_> = inliers.iter().map(|&k| frame_px[k]).collect();
        let s_in: Vec<_> = inliers.iter().map(|&k| position(k)).collect();
        Some(ScanTransform::fit(TransformModel::Similarity, &f_in, &s_in).unwrap_or(s))
    }

    /// Of the similarities through two of the `candidates` marks (at `position`) that do not
    /// rescale the scan beyond the tolerance, the one most marks lie within `tolerance` of
    /// (the smaller sum of their distances breaking ties).
    fn best_pair_similarity(
        &self,
        candidates: &[usize],
        position: &dyn Fn(usize) -> Vector2<f64>,
        tolerance: f64,
    ) -> Option<ScanTransform> {
        let (frame_px, options) = (&self.frame_px, self.options);
        let mut similarity = None;
        let mut best = (0usize, f64::INFINITY);
        for (a, &i) in candidates.iter().enumerate() {
            for &j in &candidates[a + 1..] {
                let Ok(s) = ScanTransform::fit(
                    TransformModel::Similarity,
                    &[frame_px[i], frame_px[j]],
                    &[position(i), position(j)],
                ) else {
                    continue;
                };
                // A scan is not rescaled by more than the tolerance allowed for the certificate.
                let (big, small) = s.scales_at(&frame_px[i]);
                if big > 1.0 + 5.0 * options.scale_tolerance
                    || small < 1.0 - 5.0 * options.scale_tolerance
                {
                    continue;
                }
                let (mut count, mut sum) = (0, 0.0);
                for &k in candidates {
                    let d = (s.scan_from_frame(&frame_px[k]) - position(k)).norm();
                    if d < tolerance {
                        count += 1;
                        sum += d;
                    }
                }
                if count > best.0 || (count == best.0 && sum < best.1) {
                    best = (count, sum);
                    similarity = Some(s);
                }
            }
        }
        similarity
    }

    /// The frame centred on the scan, unscaled: the similarity when the marks agree on none.
    fn centred_similarity(&self) -> Result<ScanTransform, FilmError> {
        let (sw, sh) = (self.scan.width() as f64, self.scan.height() as f64);
        let (fw, fh) = (self.frame.width() as f64, self.frame.height() as f64);
        ScanTransform::from_matrix(
            TransformModel::Similarity,
            nalgebra::Matrix3::new(
                1.0,
                0.0,
                0.5 * (sw - fw),
                0.0,
                1.0,
                0.5 * (sh - fh),
                0.0,
                0.0,
                1.0,
            ),
        )
    }

    /// Every mark refined by least-squares matching where `similarity` puts it, from its coarse
    /// position when that agrees (within `tolerance`), else from a search around the prediction.
    fn refine_marks(
        &self,
        coarse: &[CoarseMark],
        similarity: &ScanTransform,
        tolerance: f64,
    ) -> Vec<MarkMeasurement> {
        let m = similarity.scan_from_frame_matrix();
        let linear = Matrix2::new(m[(0, 0)], m[(0, 1)], m[(1, 0)], m[(1, 1)]);
        let local_radius = tolerance + 4.0;
        let options = self.options;
        (0..self.frame_px.len())
            .map(|k| {
                if let Some(p) = self.given_at(k) {
                    return MarkMeasurement {
                        mark: k,
                        scan_px: Some(p),
                        correlation: 1.0,
                        residual_px: None,
                        status: MarkStatus::Given,
                    };
                }
                let predicted = similarity.scan_from_frame(&self.frame_px[k]);
                let start = match coarse[k] {
                    Some((p, _)) if (p - predicted).norm() < tolerance => Some(p),
                    _ => ncc_search(&self.grey, self.template, &predicted, local_radius)
                        .filter(|peak| peak.correlation >= 0.5 * options.min_correlation)
                        .map(|peak| peak.centre),
                };
                let refined = start
                    .and_then(|s| least_squares_match(self.scan, self.template, &s, &linear, 3.0));
                match refined {
                    Some(r) if r.correlation >= options.min_correlation => MarkMeasurement {
                        mark: k,
                        scan_px: Some(r.centre),
                        correlation: r.correlation,
                        residual_px: None,
                        status: MarkStatus::Measured,
                    },
                    other => MarkMeasurement {
                        mark: k,
                        scan_px: None,
                        correlation: other.map_or(0.0, |r| r.correlation),
                        residual_px: None,
                        status: MarkStatus::NotFound,
                    },
                }
            })
            .collect()
    }

    /// The transform for `n` marks: projective from eight when asked for, affine from three,
    /// else a similarity.
    fn model_for(&self, n: usize) -> TransformModel {
        if self.options.projective_from_eight && n >= 8 {
            TransformModel::Projective
        } else if n >= 3 {
            TransformModel::Affine
        } else {
            TransformModel::Similarity
        }
    }

    /// The transform fitted to the marks used, after rejecting the worst measured mark while
    /// its residual exceeds the limit and enough marks remain; every found mark's residual set.
    fn fit_rejecting_worst(
        &self,
        marks: &mut [MarkMeasurement],
    ) -> Result<ScanTransform, FilmError> {
        let frame_px = &self.frame_px;
        loop {
            let used: Vec<usize> = marks
                .iter()
                .filter(|m| matches!(m.status, MarkStatus::Measured | MarkStatus::Given))
                .map(|m| m.mark)
                .collect();
            if used.len() < 2 {
                return Err(FilmError::TooFewMarks {
                    found: used.len(),
                    needed: 3,
                    model: "affine",
                });
            }
            let model = self.model_for(used.len());
            let f_used: Vec<_> = used.iter().map(|&k| frame_px[k]).collect();
            let s_used: Vec<_> = used
                .iter()
                .map(|&k| marks[k].scan_px.unwrap_or_default())
                .collect();
            let t = ScanTransform::fit(model, &f_used, &s_used)?;
            for m in marks.iter_mut() {
                m.residual_px = m
                    .scan_px
                    .map(|p| (t.scan_from_frame(&frame_px[m.mark]) - p).norm());
            }
            let worst = used
                .iter()
                .copied()
                .filter(|&k| marks[k].status == MarkStatus::Measured)
                .max_by(|&a, &b| {
                    marks[a]
                        .residual_px
                        .unwrap_or(0.0)
                        .total_cmp(&marks[b].residual_px.unwrap_or(0.0))
                });
            match worst {
                Some(k)
                    if marks[k].residual_px.unwrap_or(0.0) > self.options.max_residual_px
                        && used.len() > model.min_marks() + 1 =>
                {
                    marks[k].status = MarkStatus::Rejected;
                }
                _ => return Ok(t),
            }
        }
    }
}

/// Adds a warning for every rejected mark and every used mark whose residual exceeds the limit.
fn push_residual_warnings(
    marks: &[MarkMeasurement],
    frame: &FilmFrame,
    options: &MeasureOptions,
    warnings: &mut Vec<String>,
) {
    for m in marks {
        let name = &frame.marks()[m.mark].name;
        let r = m.residual_px.unwrap_or(0.0);
        match m.status {
            MarkStatus::Rejected => warnings.push(format!(
                "mark {name} rejected: {r:.2} px from the interior orientation of the other marks \
                 (its measurement or its certificate coordinates are wrong)"
            )),
            MarkStatus::Measured | MarkStatus::Given if r > options.max_residual_px => warnings
                .push(format!(
                    "mark {name}: residual {r:.2} px > {} px, and too few marks to reject it",
                    options.max_residual_px
                )),
            _ => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Matrix3;

    use super::*;
    use crate::frame::{FiducialMark, FrameMargins};
    use crate::template::tests::ring_and_dot;

    /// Eight marks of a certificate (mm), 0.45 mm pixels: a 500 × 500 frame.
    fn frame() -> FilmFrame {
        let marks = [
            ("TL", -112.5, 112.5),
            ("T", 0.0, 112.5),
            ("TR", 112.5, 112.5),
            ("R", 112.5, 0.0),
            ("BR", 112.5, -112.5),
            ("B", 0.0, -112.5),
            ("BL", -112.5, -112.5),
            ("L", -112.5, 0.0),
        ]
        .into_iter()
        .map(|(name, x, y)| FiducialMark {
            name: name.into(),
            mm: Vector2::new(x + 0.4, y - 0.7),
        })
        .collect();
        FilmFrame::new(marks, 0.45, FrameMargins::default()).unwrap()
    }

    /// A 560 × 580 scan of dark film with the ring marks where `truth` puts them, noise of
    /// `noise` and a bright blob (a scratch) near one mark.
    fn scan(frame: &FilmFrame, truth: &ScanTransform, noise: f64, skip: Option<usize>) -> Vec<f32> {
        let (w, h) = (560, 580);
        let mut data = vec![0.1f32; w * h];
        for k in 0..frame.marks().len() {
            if Some(k) == skip {
                continue;
            }
            let c = truth.scan_from_frame(&frame.mark_px(k));
            let angle = truth.rotation_at(&frame.mark_px(k));
            let patch = ring_and_dot(
                31,
                Vector2::new(15.0 + c.x.fract(), 15.0 + c.y.fract()),
                angle,
                1.0,
            );
            let (x0, y0) = (c.x.floor() as isize - 15, c.y.floor() as isize - 15);
            for j in 0..31 {
                for i in 0..31 {
                    let (x, y) = (x0 + i as isize, y0 + j as isize);
                    if x >= 0 && y >= 0 && (x as usize) < w && (y as usize) < h {
                        data[y as usize * w + x as usize] = patch.data[j * 31 + i];
                    }
                }
            }
        }
        let mut rng = timesift_core::SeededRng::new(11);
        for v in &mut data {
            *v += (noise * rng.normal()) as f32;
        }
        data
    }

    fn template() -> Template {
        Template::new(ring_and_dot(17, Vector2::new(8.5, 8.5), 0.0, 1.0)).unwrap()
    }

    fn truth() -> ScanTransform {
        let (s, c) = 0.012f64.sin_cos();
        let (sx, sy, shear) = (0.99968, 0.99981, 2e-4);
        ScanTransform::from_matrix(
            TransformModel::Affine,
            Matrix3::new(
                c * sx,
                c * shear - s * sy,
                41.3,
                s * sx,
                s * shear + c * sy,
                27.9,
                0.0,
                0.0,
                1.0,
            ),
        )
        .unwrap()
    }

    #[test]
    fn every_mark_of_a_noisy_scan_is_found_and_the_scan_transform_recovered() {
        let frame = frame();
        let truth = truth();
        let data = scan(&frame, &truth, 0.02, None);
        let view = ImageView::new(560, 580, 1, &data).unwrap();
        let o = orient_scan(&view, &frame, &template(), &[], &MeasureOptions::default()).unwrap();
        assert!(o.warnings.is_empty(), "{:?}", o.warnings);
        assert_eq!(o.transform.model(), TransformModel::Affine);
        let projective = MeasureOptions {
            projective_from_eight: true,
            ..MeasureOptions::default()
        };
        let p = orient_scan(&view, &frame, &template(), &[], &projective).unwrap();
        assert_eq!(p.transform.model(), TransformModel::Projective);
        assert!(p.rms_px < 0.05, "{}", p.rms_px);
        for m in &o.marks {
            let expected = truth.scan_from_frame(&frame.mark_px(m.mark));
            let error = (m.scan_px.unwrap() - expected).norm();
            assert!(error < 0.05, "mark {}: {error}", frame.marks()[m.mark].name);
        }
        for p in [Vector2::new(250.0, 250.0), Vector2::new(10.0, 490.0)] {
            assert!((o.transform.scan_from_frame(&p) - truth.scan_from_frame(&p)).norm() < 0.05);
        }
        assert!(o.rms_px < 0.05, "{}", o.rms_px);
    }

    #[test]
    fn a_missing_mark_and_a_wrong_coordinate_are_named_and_the_others_go_on() {
        let good = frame();
        let truth = truth();
        let data = scan(&good, &truth, 0.02, Some(2));
        // The certificate has R 2 mm too far right.
        let mut marks = good.marks().to_vec();
        marks[3].mm.x += 2.0;
        let frame = FilmFrame::new(marks, 0.45, FrameMargins::default()).unwrap();
        let view = ImageView::new(560, 580, 1, &data).unwrap();
        let o = orient_scan(&view, &frame, &template(), &[], &MeasureOptions::default()).unwrap();
        assert_eq!(o.marks[2].status, MarkStatus::NotFound);
        assert_eq!(o.marks[3].status, MarkStatus::Rejected);
        assert!(
            o.warnings
                .iter()
                .any(|w| w.starts_with("mark TR not found")),
            "{:?}",
            o.warnings
        );
        assert!(
            o.warnings.iter().any(|w| w.starts_with("mark R rejected")),
            "{:?}",
            o.warnings
        );
        assert_eq!(o.transform.model(), TransformModel::Affine);
        // The wrong mark widens the frame: compare where a certificate position lands.
        let mm = Vector2::new(30.0, -20.0);
        let found = o.transform.scan_from_frame(&frame.frame_from_mm(&mm));
        let expected = truth.scan_from_frame(&good.frame_from_mm(&mm));
        assert!((found - expected).norm() < 0.1, "{found} {expected}");
    }

    #[test]
    fn a_mark_given_by_hand_replaces_the_search() {
        let frame = frame();
        let truth = truth();
        let data = scan(&frame, &truth, 0.02, Some(0));
        let view = ImageView::new(560, 580, 1, &data).unwrap();
        let hand = truth.scan_from_frame(&frame.mark_px(0)) + Vector2::new(0.1, 0.0);
        let o = orient_scan(
            &view,
            &frame,
            &template(),
            &[(0, hand)],
            &MeasureOptions::default(),
        )
        .unwrap();
        assert_eq!(o.marks[0].status, MarkStatus::Given);
        assert_eq!(o.marks[0].scan_px, Some(hand));
        assert!(o.warnings.is_empty(), "{:?}", o.warnings);
    }

    #[test]
    fn bad_inputs_are_one_line_errors() {
        let frame = frame();
        let data = vec![0.1f32; 300 * 300];
        let small = ImageView::new(300, 300, 1, &data).unwrap();
        let err =
            orient_scan(&small, &frame, &template(), &[], &MeasureOptions::default()).unwrap_err();
        assert!(err.to_string().contains("disagree with the scan"), "{err}");
        let truth = truth();
        let data = scan(&frame, &truth, 0.0, None);
        let view = ImageView::new(560, 580, 1, &data).unwrap();
        let big = Template::new(ring_and_dot(160, Vector2::new(80.0, 80.0), 0.0, 8.0)).unwrap();
        let options = MeasureOptions {
            search_fraction: 0.1,
            ..MeasureOptions::default()
        };
        let err = orient_scan(&view, &frame, &big, &[], &options).unwrap_err();
        assert!(
            err.to_string().contains("larger than the search window"),
            "{err}"
        );
        let blank = vec![0.1f32; 560 * 580];
        let view = ImageView::new(560, 580, 1, &blank).unwrap();
        let err =
            orient_scan(&view, &frame, &template(), &[], &MeasureOptions::default()).unwrap_err();
        assert!(
            matches!(err, FilmError::TooFewMarks { found: 0, .. }),
            "{err}"
        );
    }
}
