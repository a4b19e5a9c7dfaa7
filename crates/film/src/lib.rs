//! Scanned aerial film: the fiducial marks of a film camera's calibration certificate found in
//! every scan, an interior orientation per scan (frame pixels → scan pixels: affine, or
//! projective with eight marks or more), the film mask (the film's edge, the marks and the data
//! strip are the same in every scan and must never be matched), and each scan resampled to the
//! camera's frame.
//!
//! Why resample, as MicMac does, rather than carry a transform per image inside the camera
//! model: after resampling, every scan of a film camera is an image of one camera with one
//! calibration, so features, matching, the bundle adjustment, dense matching, orthomosaics and
//! every export see an ordinary frame camera and need no film-specific code; the price is one
//! bicubic interpolation of each scan (its sharpness is kept: the frame has the scan's pixel
//! size) and the time to resample it when it is read.
//!
//! Invariants: reads and writes no file (the root does, through `timesift-io`); knows nothing
//! of projects, epochs or stages — one call orients one scan; a scan is never changed, only
//! read; every bad input (a certificate without a frame, a template larger than the search, a
//! scan smaller than the marks) is a [`FilmError`], never NaN; a mark that is not found or does
//! not fit is reported by name in the scan's warnings, and the other marks go on.
//!
//! # Example
//!
//! Four marks of a (tiny) certificate, a scan in which the frame lies shifted and rotated, and
//! the interior orientation recovered from the marks:
//!
//! ```
//! use nalgebra::{Matrix3, Vector2};
//! use timesift_film::{
//!     FiducialMark, FilmFrame, FrameMargins, GreyRaster, ImageView, MeasureOptions,
//!     ScanTransform, Template, TransformModel, orient_scan, resample_to_frame,
//! };
//!
//! // A bright disc of radius 3 px on dark film, drawn with 4 × 4 samples per pixel.
//! let disc = |x: f64, y: f64, cx: f64, cy: f64| -> f32 {
//!     let mut inside = 0;
//!     for s in 0..16 {
//!         let (dx, dy) = (x + (s % 4) as f64 * 0.25 + 0.125 - cx, y + (s / 4) as f64 * 0.25 + 0.125 - cy);
//!         inside += (dx * dx + dy * dy < 9.0) as i32;
//!     }
//!     0.1 + 0.8 * inside as f32 / 16.0
//! };
//! let template = Template::new(GreyRaster {
//!     width: 13,
//!     height: 13,
//!     data: (0..169).map(|k| disc((k % 13) as f64, (k / 13) as f64, 6.5, 6.5)).collect(),
//! })?;
//! let marks: Vec<FiducialMark> = [("TL", -5.0, 5.0), ("TR", 5.0, 5.0), ("BR", 5.0, -5.0), ("BL", -5.0, -5.0)]
//!     .into_iter()
//!     .map(|(name, x, y)| FiducialMark { name: name.into(), mm: Vector2::new(x, y) })
//!     .collect();
//! let frame = FilmFrame::new(marks, 0.1, FrameMargins::default())?; // 100 × 100 pixels
//!
//! // The scan: 140 × 140 pixels, the frame rotated by 0.5° and shifted by (23.4, 16.7).
//! let (s, c) = 0.5f64.to_radians().sin_cos();
//! let truth = ScanTransform::from_matrix(
//!     TransformModel::Affine,
//!     Matrix3::new(c, -s, 23.4, s, c, 16.7, 0.0, 0.0, 1.0),
//! )?;
//! let centres: Vec<Vector2<f64>> = (0..4).map(|k| truth.scan_from_frame(&frame.mark_px(k))).collect();
//! let scan: Vec<f32> = (0..140 * 140)
//!     .map(|k| {
//!         let (x, y) = ((k % 140) as f64, (k / 140) as f64);
//!         centres.iter().map(|p| disc(x, y, p.x, p.y)).fold(0.1, f32::max)
//!     })
//!     .collect();
//! let view = ImageView::new(140, 140, 1, &scan)?;
//!
//! let orientation = orient_scan(&view, &frame, &template, &[], &MeasureOptions::default())?;
//! for (m, truth) in orientation.marks.iter().zip(&centres) {
//!     assert!((m.scan_px.unwrap() - truth).norm() < 0.1);
//! }
//! let frame_image = resample_to_frame(&view, &orientation.transform, &frame);
//! assert_eq!((frame_image.width, frame_image.height), (100, 100));
//! # Ok::<(), timesift_film::FilmError>(())
//! ```
#![warn(missing_docs, unnameable_types)]

mod distortion;
mod error;
mod frame;
mod measure;
mod raster;
mod resample;
mod target;
mod template;
mod transform;

pub use distortion::{RadialFit, radial_from_certificate};
pub use error::FilmError;
pub use frame::{FiducialMark, FilmFrame, FrameMargins};
pub use measure::{MarkMeasurement, MarkStatus, MeasureOptions, ScanOrientation, orient_scan};
pub use raster::{GreyRaster, ImageView};
pub use resample::{FrameImage, resample_to_frame};
pub use target::locate_target;
pub use template::Template;
pub use transform::{ScanTransform, TransformModel};
