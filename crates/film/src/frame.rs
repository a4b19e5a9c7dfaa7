//! The camera frame of a film camera, from its calibration certificate: the fiducial marks in
//! millimetres (x right, y up, any origin), the scan's pixel size, and the raster every scan of
//! the camera is resampled to — the marks' bounding box at that pixel size, y down — with the
//! part of it that holds the photograph (the film mask).

use nalgebra::Vector2;

use crate::FilmError;

/// A fiducial mark of a calibration certificate.
#[derive(Debug, Clone, PartialEq)]
pub struct FiducialMark {
    /// Its name on the certificate (`TL`, `1`, `side-left`…).
    pub name: String,
    /// Millimetres, certificate frame (x right, y up).
    pub mm: Vector2<f64>,
}

/// How much of the frame next to its edges is left out of the usable photograph: the film's
/// edge, the marks and the data strip lie there, and they are the same in every scan, so a
/// keypoint on them would tie every image to every other at one pixel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameMargins {
    /// Band along the frame's edges, as a fraction of its shorter side.
    pub edge_fraction: f64,
    /// Radius of the disc left out around every mark, pixels (at least the template's half
    /// diagonal).
    pub mark_radius_px: f64,
}

impl Default for FrameMargins {
    fn default() -> Self {
        FrameMargins {
            edge_fraction: 0.03,
            mark_radius_px: 0.0,
        }
    }
}

/// The frame of one film camera: where each mark lies in frame pixels, and which frame pixels
/// hold the photograph.
///
/// Invariant: at least three marks, not collinear, with distinct names; the frame is the marks'
/// bounding box at `pixel_mm`, its centre the box's centre.
#[derive(Debug, Clone, PartialEq)]
pub struct FilmFrame {
    marks: Vec<FiducialMark>,
    pixel_mm: f64,
    centre_mm: Vector2<f64>,
    width: u32,
    height: u32,
    usable_min: Vector2<f64>,
    usable_max: Vector2<f64>,
    mark_radius_px: f64,
}

impl FilmFrame {
    /// The frame of a certificate's marks at a scan pixel size of `pixel_mm`.
    pub fn new(
        marks: Vec<FiducialMark>,
        pixel_mm: f64,
        margins: FrameMargins,
    ) -> Result<FilmFrame, FilmError> {
        if !(pixel_mm.is_finite() && pixel_mm > 0.0) {
            return Err(FilmError::InvalidOption {
                name: "pixel_mm",
                value: pixel_mm,
                expected: "a positive pixel size in millimetres",
            });
        }
        if !(margins.edge_fraction.is_finite() && (0.0..0.25).contains(&margins.edge_fraction)) {
            return Err(FilmError::InvalidOption {
                name: "edge_fraction",
                value: margins.edge_fraction,
                expected: "a fraction in [0, 0.25)",
            });
        }
        if marks.len() < 3 {
            return Err(FilmError::InvalidMarks(format!(
                "{} given; at least 3 are needed for an interior orientation",
                marks.len()
            )));
        }
        for (k, m) in marks.iter().enumerate() {
            if !(m.mm.x.is_finite() && m.mm.y.is_finite()) {
                return Err(FilmError::InvalidMarks(format!(
                    "mark {} has coordinates ({}, {})",
                    m.name, m.mm.x, m.mm.y
                )));
            }
            if marks[..k].iter().any(|o| o.name == m.name) {
                return Err(FilmError::InvalidMarks(format!(
                    "mark {} is given twice",
                    m.name
                )));
            }
        }
        let (mut lo, mut hi) = (marks[0].mm, marks[0].mm);
        for m in &marks {
            lo = lo.inf(&m.mm);
            hi = hi.sup(&m.mm);
        }
        let extent = hi - lo;
        // Collinear marks: the largest triangle is small against the extent.
        let mut area: f64 = 0.0;
        for a in 0..marks.len() {
            for b in a + 1..marks.len() {
                for c in b + 1..marks.len() {
                    let (u, v) = (marks[b].mm - marks[a].mm, marks[c].mm - marks[a].mm);
                    area = area.max(0.5 * (u.x * v.y - u.y * v.x).abs());
                }
            }
        }
        let size = extent.x.max(extent.y);
        if area < 0.05 * size * size {
            return Err(FilmError::InvalidMarks(
                "the marks are (nearly) collinear: they span no frame".into(),
            ));
        }
        let (width, height) = ((extent.x / pixel_mm).round(), (extent.y / pixel_mm).round());
        if width < 16.0 || height < 16.0 || width > 1e6 || height > 1e6 {
            return Err(FilmError::InvalidMarks(format!(
                "the marks span {:.3} × {:.3} mm, {width} × {height} pixels of {pixel_mm} mm",
                extent.x, extent.y
            )));
        }
        let band = margins.edge_fraction * width.min(height);
        let band = band.max(margins.mark_radius_px.max(0.0) + 2.0);
        Ok(FilmFrame {
            marks,
            pixel_mm,
            centre_mm: 0.5 * (lo + hi),
            width: width as u32,
            height: height as u32,
            usable_min: Vector2::new(band, band),
            usable_max: Vector2::new(width - band, height - band),
            mark_radius_px: margins.mark_radius_px.max(0.0),
        })
    }

    /// The marks, in the order given.
    pub fn marks(&self) -> &[FiducialMark] {
        &self.marks
    }

    /// Scan pixel size, millimetres.
    pub fn pixel_mm(&self) -> f64 {
        self.pixel_mm
    }

    /// Frame width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Frame height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The frame pixel of a certificate position (mm, y up).
    pub fn frame_from_mm(&self, mm: &Vector2<f64>) -> Vector2<f64> {
        let d = (mm - self.centre_mm) / self.pixel_mm;
        Vector2::new(
            0.5 * self.width as f64 + d.x,
            0.5 * self.height as f64 - d.y,
        )
    }

    /// The certificate position (mm, y up) of a frame pixel.
    pub fn mm_from_frame(&self, px: &Vector2<f64>) -> Vector2<f64> {
        let d = Vector2::new(
            px.x - 0.5 * self.width as f64,
            0.5 * self.height as f64 - px.y,
        );
        self.centre_mm + d * self.pixel_mm
    }

    /// Frame pixel of mark `k`.
    pub fn mark_px(&self, k: usize) -> Vector2<f64> {
        self.frame_from_mm(&self.marks[k].mm)
    }

    /// The principal point of the certificate (mm) as the offset from the frame's centre in
    /// pixels, x right and y down: the `cx`, `cy` of the `brown` camera model.
    pub fn principal_point_offset(&self, principal_point_mm: &Vector2<f64>) -> Vector2<f64> {
        let p = self.frame_from_mm(principal_point_mm);
        Vector2::new(
            p.x - 0.5 * self.width as f64,
            p.y - 0.5 * self.height as f64,
        )
    }

    /// A focal length of the certificate (mm) in frame pixels.
    pub fn focal_px(&self, focal_mm: f64) -> f64 {
        focal_mm / self.pixel_mm
    }

    /// Whether a frame position holds the photograph: inside the band along the edges and
    /// outside every mark's disc.
    pub fn usable(&self, px: &Vector2<f64>) -> bool {
        if px.x < self.usable_min.x
            || px.y < self.usable_min.y
            || px.x > self.usable_max.x
            || px.y > self.usable_max.y
        {
            return false;
        }
        let r2 = self.mark_radius_px * self.mark_radius_px;
        (0..self.marks.len()).all(|k| (self.mark_px(k) - px).norm_squared() > r2)
    }

    /// The nearest point of the usable rectangle (marks' discs aside) to a frame position.
    pub(crate) fn clamp_to_usable(&self, px: &Vector2<f64>) -> Vector2<f64> {
        Vector2::new(
            px.x.clamp(self.usable_min.x, self.usable_max.x),
            px.y.clamp(self.usable_min.y, self.usable_max.y),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn eight_marks() -> Vec<FiducialMark> {
        let mut marks = Vec::new();
        for (name, x, y) in [
            ("TL", -106.0, 106.0),
            ("T", 0.0, 113.0),
            ("TR", 106.0, 106.0),
            ("R", 113.0, 0.0),
            ("BR", 106.0, -106.0),
            ("B", 0.0, -113.0),
            ("BL", -106.0, -106.0),
            ("L", -113.0, 0.0),
        ] {
            marks.push(FiducialMark {
                name: name.into(),
                mm: Vector2::new(x + 5.0, y - 3.0),
            });
        }
        marks
    }

    #[test]
    fn the_frame_is_the_marks_bounding_box_with_y_down() {
        let frame = FilmFrame::new(eight_marks(), 0.113, FrameMargins::default()).unwrap();
        assert_eq!((frame.width(), frame.height()), (2000, 2000));
        let left = frame.mark_px(7);
        let top = frame.mark_px(1);
        assert!((left - Vector2::new(0.0, 1000.0)).norm() < 1e-9, "{left}");
        assert!((top - Vector2::new(1000.0, 0.0)).norm() < 1e-9, "{top}");
        let p = Vector2::new(12.3, -45.6);
        assert!((frame.mm_from_frame(&frame.frame_from_mm(&p)) - p).norm() < 1e-12);
        // The principal point 0.113 mm right of and above the marks' centre.
        let pp = frame.principal_point_offset(&Vector2::new(5.113, -2.887));
        assert!((pp - Vector2::new(1.0, -1.0)).norm() < 1e-9, "{pp}");
    }

    #[test]
    fn the_edges_and_the_marks_are_not_usable() {
        let mut marks = eight_marks();
        marks.push(FiducialMark {
            name: "centre".into(),
            mm: Vector2::new(5.0, -3.0),
        });
        let margins = FrameMargins {
            edge_fraction: 0.03,
            mark_radius_px: 20.0,
        };
        let frame = FilmFrame::new(marks, 0.113, margins).unwrap();
        assert!(!frame.usable(&Vector2::new(59.0, 1000.0)));
        assert!(frame.usable(&Vector2::new(61.0, 700.0)));
        assert!(!frame.usable(&Vector2::new(1010.0, 1010.0)));
        assert!(frame.usable(&Vector2::new(1030.0, 1010.0)));
    }

    #[test]
    fn bad_certificates_are_errors() {
        let m = |name: &str, x: f64, y: f64| FiducialMark {
            name: name.into(),
            mm: Vector2::new(x, y),
        };
        let ok = FrameMargins::default();
        assert!(FilmFrame::new(vec![m("a", 0.0, 0.0), m("b", 100.0, 0.0)], 0.02, ok).is_err());
        let line = vec![m("a", 0.0, 0.0), m("b", 100.0, 1.0), m("c", 200.0, 2.0)];
        assert!(FilmFrame::new(line, 0.02, ok).is_err());
        let twice = vec![m("a", 0.0, 0.0), m("a", 100.0, 0.0), m("c", 0.0, 100.0)];
        let err = FilmFrame::new(twice, 0.02, ok).unwrap_err();
        assert!(err.to_string().contains("mark a is given twice"), "{err}");
        let corners = vec![m("a", 0.0, 0.0), m("b", 100.0, 0.0), m("c", 0.0, 100.0)];
        assert!(FilmFrame::new(corners.clone(), 0.0, ok).is_err());
        assert!(FilmFrame::new(corners, 0.02, ok).is_ok());
    }
}
