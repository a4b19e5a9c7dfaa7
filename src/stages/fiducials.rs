//! The fiducials step: the marks of every scan of a film camera measured, each scan given an
//! interior orientation, and the results written for people (`out/fiducials.csv`, a contact
//! sheet `out/fiducials.png`) and for the stages (`out/fiducials.json`, read by
//! [`crate::film::ImageSource`]). The features stage runs it first when a camera is film;
//! `timesift fiducials` runs it alone. It is redone only when a scan, a template, the
//! certificate's marks or `fiducials.csv` change.

use std::fmt::Write as _;

use nalgebra::Vector2;
use rayon::prelude::*;
use timesift_film::{ImageView, MarkStatus, orient_scan};

use super::cache::file_stamp;
use crate::film::FilmCamera;
use crate::report::{FiducialsReport, MarkReport, ScanReport, read_json, write_json};
use crate::{Project, ProjectError};

/// What the step did.
#[derive(Debug, Clone, PartialEq)]
pub struct FiducialsOutcome {
    /// Every scan's marks and interior orientation.
    pub report: FiducialsReport,
    /// Whether the scans were measured in this run (else the results were up to date).
    pub measured: bool,
}

impl FiducialsOutcome {
    /// One line for the run's log: scans, marks used, the largest interior-orientation RMS, and
    /// the scans that could not be oriented.
    pub fn summary(&self) -> String {
        let scans = &self.report.images;
        let marks: usize = scans.iter().map(|s| s.marks.len()).sum();
        let used = scans
            .iter()
            .flat_map(|s| &s.marks)
            .filter(|m| m.status == "measured" || m.status == "given")
            .count();
        let worst = scans.iter().filter_map(|s| s.rms_px).fold(0.0f64, f64::max);
        let failed = scans.iter().filter(|s| s.error.is_some()).count();
        format!(
            "{}fiducials of {} scans: {used} of {marks} marks used, interior orientation RMS ≤ {worst:.3} px{}",
            if self.measured { "" } else { "up to date: " },
            scans.len(),
            if failed > 0 {
                format!(", {failed} scans not oriented")
            } else {
                String::new()
            }
        )
    }
}

/// Measures the marks of every scan whose results are out of date; `None` when no camera of the
/// project is film.
pub fn fiducials_stage(project: &Project) -> Result<Option<FiducialsOutcome>, ProjectError> {
    if project.film.is_empty() {
        return Ok(None);
    }
    let layout = project.layout();
    let scans: Vec<usize> = (0..project.images.len())
        .filter(|&i| project.film_camera(i).is_some())
        .collect();
    let settings = serde_json::json!({
        "cameras": project.config.cameras.iter()
            .filter(|c| c.fiducials.is_some())
            .map(|c| format!("{c:?}"))
            .collect::<Vec<_>>(),
        "templates": project.film.values()
            .map(|f| file_stamp(&f.template_path))
            .collect::<Vec<_>>(),
        "hand": format!("{:?}", project.fiducial_marks),
        "scans": scans.iter()
            .map(|&i| (project.images[i].name.clone(), file_stamp(&project.image_path(i.into()))))
            .collect::<Vec<_>>(),
    });
    let record = layout.fiducials_settings();
    let mut outputs = vec![
        layout.fiducials_json(),
        layout.fiducials_csv(),
        layout.fiducials_sheet(),
    ];
    outputs.extend(project.film.keys().map(|c| layout.fiducials_frame(c)));
    let recorded = crate::report::read_sealed_json::<serde_json::Value>(&record).ok();
    if recorded.as_ref() == Some(&settings) && outputs.iter().all(|p| p.exists()) {
        let report = read_json::<FiducialsReport>(&layout.fiducials_json())?;
        return Ok(Some(FiducialsOutcome {
            report,
            measured: false,
        }));
    }
    let (images, crops): (Vec<ScanReport>, Vec<Vec<MarkCrop>>) = scans
        .par_iter()
        .filter_map(|&i| Some((i, project.film_camera(i)?)))
        .map(|(i, film)| measure_one(project, i, film))
        .unzip();
    let report = FiducialsReport { images };
    write_json(&layout.fiducials_json(), &report)?;
    timesift_io::fsutil::write_bytes_atomically(
        &layout.fiducials_csv(),
        fiducials_csv(&report).as_bytes(),
    )?;
    write_contact_sheet(&report, &crops, &layout.fiducials_sheet())?;
    write_frame_examples(project, &report)?;
    crate::report::write_sealed_json(&record, &settings)?;
    Ok(Some(FiducialsOutcome {
        report,
        measured: true,
    }))
}

/// One scan measured, with a crop of the scan around each mark for the contact sheet; a scan
/// that cannot be read or oriented gives a report with its error, so that the others go on.
fn measure_one(project: &Project, i: usize, film: &FilmCamera) -> (ScanReport, Vec<MarkCrop>) {
    let name = project.images[i].name.clone();
    let camera = project.epochs[project.images[i].epoch.index()]
        .camera_group
        .clone();
    let marks = film.frame.marks();
    let given: Vec<(usize, Vector2<f64>)> = project
        .fiducial_marks
        .iter()
        .filter(|m| m.image == name)
        .filter_map(|m| {
            let k = marks.iter().position(|k| k.name == m.mark)?;
            Some((k, m.pixel))
        })
        .collect();
    let failed = |error: String| ScanReport {
        image: name.clone(),
        camera: camera.clone(),
        marks: marks
            .iter()
            .map(|k| MarkReport {
                mark: k.name.clone(),
                uv: None,
                correlation: 0.0,
                residual_px: None,
                status: "not found".into(),
            })
            .collect(),
        model: String::new(),
        scan_from_frame: None,
        rms_px: None,
        scales: None,
        rotation_deg: None,
        warnings: Vec::new(),
        error: Some(error),
    };
    let scan = match timesift_io::image::read_grey(&project.image_path(i.into())) {
        Ok(s) => s,
        Err(e) => return (failed(e.to_string()), Vec::new()),
    };
    let view = match ImageView::new(scan.width as usize, scan.height as usize, 1, &scan.data) {
        Ok(v) => v,
        Err(e) => return (failed(e.to_string()), Vec::new()),
    };
    let orientation = match orient_scan(&view, &film.frame, &film.template, &given, &film.measure) {
        Ok(o) => o,
        Err(e) => return (failed(e.to_string()), Vec::new()),
    };
    let half = (1.4 * film.template.half_diagonal()).ceil() as usize;
    let crops = orientation
        .marks
        .iter()
        .map(|r| {
            let centre = r.scan_px.unwrap_or_else(|| {
                orientation
                    .transform
                    .scan_from_frame(&film.frame.mark_px(r.mark))
            });
            MarkCrop::cut(&scan, centre, half, r.scan_px, r.status)
        })
        .collect();
    let m = orientation.transform.scan_from_frame_matrix();
    let centre = Vector2::new(
        0.5 * film.frame.width() as f64,
        0.5 * film.frame.height() as f64,
    );
    let report = ScanReport {
        image: name.clone(),
        camera,
        marks: orientation
            .marks
            .iter()
            .map(|r| MarkReport {
                mark: marks[r.mark].name.clone(),
                uv: r.scan_px.map(|p| [p.x, p.y]),
                correlation: r.correlation,
                residual_px: r.residual_px,
                status: match r.status {
                    MarkStatus::Measured => "measured",
                    MarkStatus::Given => "given",
                    MarkStatus::NotFound => "not found",
                    MarkStatus::Rejected => "rejected",
                }
                .into(),
            })
            .collect(),
        model: orientation.transform.model().name().into(),
        scan_from_frame: Some([
            [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
            [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
            [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
        ]),
        rms_px: Some(orientation.rms_px),
        scales: Some([orientation.scales.0, orientation.scales.1]),
        rotation_deg: Some(orientation.transform.rotation_at(&centre).to_degrees()),
        warnings: orientation.warnings,
        error: None,
    };
    (report, crops)
}

/// `out/fiducials.csv` (docs/design.md): every mark with a position, its residual after the scan's
/// interior orientation.
fn fiducials_csv(report: &FiducialsReport) -> String {
    let mut text = String::from("image,mark,u,v,residual_px\n");
    for scan in &report.images {
        for m in &scan.marks {
            if let Some([u, v]) = m.uv {
                let residual = m.residual_px.map(|r| format!("{r:.3}")).unwrap_or_default();
                let _ = writeln!(text, "{},{},{u:.3},{v:.3},{residual}", scan.image, m.mark);
            }
        }
    }
    text
}

/// A square of a scan around one mark, for a person to check its measured centre.
#[derive(Debug, Clone)]
struct MarkCrop {
    /// Side, pixels.
    side: usize,
    /// Grey values 0–255, row-major.
    grey: Vec<u8>,
    /// The measured centre in crop pixels.
    centre: Option<Vector2<f64>>,
    /// Whether the mark is used by the interior orientation.
    used: bool,
}

impl MarkCrop {
    fn cut(
        scan: &timesift_io::image::ImageF32,
        around: Vector2<f64>,
        half: usize,
        measured: Option<Vector2<f64>>,
        status: MarkStatus,
    ) -> MarkCrop {
        let side = 2 * half;
        let x0 = around.x.round() as isize - half as isize;
        let y0 = around.y.round() as isize - half as isize;
        let (w, h) = (scan.width as isize, scan.height as isize);
        let grey = (0..side * side)
            .map(|k| {
                let (x, y) = (x0 + (k % side) as isize, y0 + (k / side) as isize);
                if x < 0 || y < 0 || x >= w || y >= h {
                    0
                } else {
                    (255.0 * scan.data[(y * w + x) as usize])
                        .round()
                        .clamp(0.0, 255.0) as u8
                }
            })
            .collect();
        MarkCrop {
            side,
            grey,
            centre: measured.map(|p| p - Vector2::new(x0 as f64, y0 as f64)),
            used: matches!(status, MarkStatus::Measured | MarkStatus::Given),
        }
    }
}

/// `out/fiducials.png`: one row per scan (numbered as in `out/fiducials.json`), one column per
/// mark (named at the top), each crop enlarged with the measured centre as a red cross; a green
/// frame around marks the interior orientation uses, a red one around rejected or missing marks.
fn write_contact_sheet(
    report: &FiducialsReport,
    crops: &[Vec<MarkCrop>],
    path: &std::path::Path,
) -> Result<(), ProjectError> {
    use image::{Rgb, RgbImage};
    let columns = report
        .images
        .iter()
        .map(|s| s.marks.len())
        .max()
        .unwrap_or(0);
    let side = crops
        .iter()
        .flatten()
        .map(|c| c.side)
        .max()
        .unwrap_or(16)
        .max(4);
    let zoom = (72 / side).max(1);
    let cell = side * zoom + 4;
    let (label, header) = (40usize, 14usize);
    let width = (label + columns * cell).max(64) as u32;
    let height = (header + report.images.len().max(1) * cell) as u32;
    let mut sheet = RgbImage::from_pixel(width, height, Rgb([255, 255, 255]));
    let black = Rgb([0, 0, 0]);
    if let Some(first) = report.images.first() {
        for (k, m) in first.marks.iter().enumerate() {
            let name: String = m.mark.chars().take(cell / 8).collect();
            timesift_change::maps::text(
                &mut sheet,
                (label + k * cell + 2) as u32,
                3,
                &name,
                1,
                black,
            );
        }
    }
    for (row, crops) in crops.iter().enumerate() {
        let y0 = header + row * cell;
        timesift_change::maps::text(
            &mut sheet,
            2,
            (y0 + cell / 2 - 4) as u32,
            &format!("{}", row + 1),
            1,
            black,
        );
        for (k, crop) in crops.iter().enumerate() {
            let x0 = label + k * cell;
            let frame = if crop.used {
                Rgb([0, 160, 0])
            } else {
                Rgb([220, 0, 0])
            };
            for t in 0..cell - 2 {
                for (x, y) in [
                    (x0 + t, y0),
                    (x0 + t, y0 + cell - 3),
                    (x0, y0 + t),
                    (x0 + cell - 3, y0 + t),
                ] {
                    sheet.put_pixel(x as u32, y as u32, frame);
                }
            }
            for j in 0..crop.side * zoom {
                for i in 0..crop.side * zoom {
                    let g = crop.grey[(j / zoom) * crop.side + i / zoom];
                    sheet.put_pixel((x0 + 2 + i) as u32, (y0 + 2 + j) as u32, Rgb([g, g, g]));
                }
            }
            if let Some(c) = crop.centre {
                let (cx, cy) = (c.x * zoom as f64, c.y * zoom as f64);
                let arm = (3 * zoom).max(6) as isize;
                for d in -arm..=arm {
                    for (x, y) in [(cx + d as f64, cy), (cx, cy + d as f64)] {
                        let (x, y) = (x.floor() as isize, y.floor() as isize);
                        let limit = (crop.side * zoom) as isize;
                        if (0..limit).contains(&x) && (0..limit).contains(&y) {
                            sheet.put_pixel(
                                (x0 as isize + 2 + x) as u32,
                                (y0 as isize + 2 + y) as u32,
                                Rgb([255, 0, 0]),
                            );
                        }
                    }
                }
            }
        }
    }
    timesift_io::image::write_png(path, width, height, 3, sheet.as_raw())?;
    Ok(())
}

/// `out/fiducials_frame_<camera>.png`: each film camera's first oriented scan resampled to its
/// frame, grey, the film mask dark — what a person draws a `[[camera]] mask` on.
fn write_frame_examples(project: &Project, report: &FiducialsReport) -> Result<(), ProjectError> {
    let source = crate::film::ImageSource::of_report(project, report)?;
    for camera in project.film.keys() {
        let Some(i) = report
            .images
            .iter()
            .filter(|s| &s.camera == camera && s.scan_from_frame.is_some())
            .find_map(|s| project.images.iter().position(|im| im.name == s.image))
        else {
            continue;
        };
        let seen = source.read(project, i, true)?;
        let usable = seen.usable.unwrap_or_default();
        let grey: Vec<u8> = seen
            .image
            .data
            .iter()
            .enumerate()
            .map(|(k, &v)| {
                let v = (255.0 * v).round().clamp(0.0, 255.0) as u8;
                if usable.get(k).copied().unwrap_or(true) {
                    v
                } else {
                    v / 4
                }
            })
            .collect();
        timesift_io::image::write_png(
            &project.layout().fiducials_frame(camera),
            seen.image.width,
            seen.image.height,
            1,
            &grey,
        )?;
    }
    Ok(())
}
