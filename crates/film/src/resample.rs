//! A scan resampled to its camera's frame: every frame pixel's value read from the scan where
//! the interior orientation puts it (bicubic), so that every scan of a film camera becomes an
//! image of one and the same camera, and the film mask beside it.

use nalgebra::Vector2;
use rayon::prelude::*;

use crate::frame::FilmFrame;
use crate::raster::ImageView;
use crate::transform::ScanTransform;

/// A scan resampled to the frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameImage {
    /// Columns (the frame's width).
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Values per pixel (the scan's).
    pub channels: usize,
    /// Values, row-major, channels interleaved, in the scan's range. Pixels that are not
    /// usable hold the nearest usable photograph (edge replicated), so that the film's edge
    /// leaves no contrast for a detector to find.
    pub data: Vec<f32>,
    /// Whether each pixel holds the photograph: inside the film mask and read from inside
    /// the scan.
    pub usable: Vec<bool>,
}

/// Resamples `scan` to `frame` through `transform` (frame pixels → scan pixels).
pub fn resample_to_frame(
    scan: &ImageView<'_>,
    transform: &ScanTransform,
    frame: &FilmFrame,
) -> FrameImage {
    let (w, h, c) = (
        frame.width() as usize,
        frame.height() as usize,
        scan.channels(),
    );
    let (lo, hi) = scan
        .data()
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
    let mut data = vec![0.0f32; w * h * c];
    let mut usable = vec![false; w * h];
    data.par_chunks_mut(w * c)
        .zip(usable.par_chunks_mut(w))
        .enumerate()
        .for_each(|(j, (row, mask))| {
            for i in 0..w {
                let p = Vector2::new(i as f64 + 0.5, j as f64 + 0.5);
                let inside = frame.usable(&p);
                let source =
                    transform.scan_from_frame(&if inside { p } else { frame.clamp_to_usable(&p) });
                mask[i] = inside && scan.supports(source.x, source.y);
                for k in 0..c {
                    let v = scan.bicubic(source.x, source.y, k) as f32;
                    row[i * c + k] = v.clamp(lo, hi);
                }
            }
        });
    FrameImage {
        width: w,
        height: h,
        channels: c,
        data,
        usable,
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::Matrix3;

    use super::*;
    use crate::frame::{FiducialMark, FrameMargins};
    use crate::transform::TransformModel;

    #[test]
    fn a_shifted_scan_comes_back_to_the_frame() {
        let marks = vec![
            FiducialMark {
                name: "a".into(),
                mm: Vector2::new(0.0, 0.0),
            },
            FiducialMark {
                name: "b".into(),
                mm: Vector2::new(4.0, 0.0),
            },
            FiducialMark {
                name: "c".into(),
                mm: Vector2::new(0.0, 4.0),
            },
        ];
        let frame = FilmFrame::new(marks, 0.1, FrameMargins::default()).unwrap();
        assert_eq!((frame.width(), frame.height()), (40, 40));
        // The scan: a smooth pattern, the frame lying 7 pixels right and 3 down in it.
        let (sw, sh) = (60, 50);
        let value = |x: f64, y: f64| 0.5 + 0.3 * (0.2 * x).sin() * (0.15 * y).cos();
        let scan: Vec<f32> = (0..sw * sh)
            .map(|k| value((k % sw) as f64 + 0.5, (k / sw) as f64 + 0.5) as f32)
            .collect();
        let view = ImageView::new(sw, sh, 1, &scan).unwrap();
        let t = ScanTransform::from_matrix(
            TransformModel::Affine,
            Matrix3::new(1.0, 0.0, 7.0, 0.0, 1.0, 3.0, 0.0, 0.0, 1.0),
        )
        .unwrap();
        let out = resample_to_frame(&view, &t, &frame);
        let (i, j) = (20, 25);
        assert!(out.usable[j * 40 + i]);
        let expected = value(i as f64 + 7.5, j as f64 + 3.5) as f32;
        assert!((out.data[j * 40 + i] - expected).abs() < 1e-6);
        // The edge band is not usable but holds the photograph's edge.
        assert!(!out.usable[20 * 40]);
        assert!(!out.usable[20 * 40 + 1]);
        assert_eq!(out.data[20 * 40], out.data[20 * 40 + 1]);
        assert_ne!(out.data[20 * 40], out.data[20 * 40 + 3]);
    }
}
