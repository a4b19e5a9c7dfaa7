//! Scanned film in a project: the film cameras of `[[camera]]` (certificate marks, template,
//! principal point), the interior orientation of every scan (`out/fiducials.json`, made by the
//! fiducials step of the features stage or `timesift fiducials`), and how every stage reads an
//! image — a digital photograph as it is, a scan resampled to its camera's frame with the film
//! mask beside it — so that no stage after it knows a scan from a photograph.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Vector2};
use timesift_film::{
    FiducialMark, FilmFrame, FrameMargins, GreyRaster, ImageView, MeasureOptions, ScanTransform,
    Template, TransformModel, resample_to_frame,
};
use timesift_io::image::ImageF32;

use crate::config::{InteriorOrientationModel, ProjectConfig};
use crate::report::{FiducialsReport, read_json};
use crate::{Project, ProjectError};

/// A film camera of the project: a camera group whose `[[camera]]` lists fiducial marks.
#[derive(Debug, Clone)]
pub struct FilmCamera {
    /// The frame its scans are resampled to, with the film mask.
    pub frame: FilmFrame,
    /// The mark's template.
    pub template: Template,
    /// The template's file.
    pub template_path: PathBuf,
    /// The certificate's principal point as `cx`, `cy` of the frame (pixels), when given.
    pub principal_point: Option<Vector2<f64>>,
    /// How the marks are searched and the scans' transforms fitted.
    pub measure: MeasureOptions,
}

/// The film cameras of `[[camera]]` tables that list fiducial marks, by camera group, with
/// their templates read and checked.
pub(crate) fn film_cameras(
    dir: &Path,
    cfg_path: &Path,
    config: &ProjectConfig,
) -> Result<BTreeMap<String, FilmCamera>, ProjectError> {
    let mut out = BTreeMap::new();
    for (i, c) in config.cameras.iter().enumerate() {
        let key = |field: &str| format!("camera[{i}].{field}");
        let Some(marks) = &c.fiducials else {
            for (field, given) in [
                ("fiducial_template", c.fiducial_template.is_some()),
                ("principal_point_mm", c.principal_point_mm.is_some()),
                (
                    "interior_orientation",
                    c.interior_orientation != InteriorOrientationModel::Affine,
                ),
            ] {
                if given {
                    return Err(ProjectError::config(
                        cfg_path,
                        key(field),
                        "only for scanned film, with [camera.fiducials]",
                    ));
                }
            }
            continue;
        };
        let pixel_mm = c.pixel_mm.ok_or_else(|| {
            ProjectError::config(
                cfg_path,
                key("pixel_mm"),
                "missing: fiducial marks need the scan's pixel size in mm",
            )
        })?;
        let template_name = c.fiducial_template.as_ref().ok_or_else(|| {
            ProjectError::config(
                cfg_path,
                key("fiducial_template"),
                "missing: a PNG of one mark as it looks in a scan is needed to find the marks",
            )
        })?;
        let template_path = dir.join(template_name);
        if !template_path.is_file() {
            return Err(ProjectError::config(
                cfg_path,
                key("fiducial_template"),
                format!("file \"{template_name}\" does not exist"),
            ));
        }
        let image = timesift_io::image::read_grey(&template_path)?;
        let template = Template::new(GreyRaster {
            width: image.width as usize,
            height: image.height as usize,
            data: image.data,
        })
        .map_err(|e| ProjectError::Path {
            path: template_path.clone(),
            message: e.to_string(),
        })?;
        let marks: Vec<FiducialMark> = marks
            .iter()
            .map(|(name, [x, y])| FiducialMark {
                name: name.clone(),
                mm: Vector2::new(*x, *y),
            })
            .collect();
        let margins = FrameMargins {
            mark_radius_px: template.half_diagonal(),
            ..FrameMargins::default()
        };
        let frame = FilmFrame::new(marks, pixel_mm, margins)
            .map_err(|e| ProjectError::config(cfg_path, key("fiducials"), e.to_string()))?;
        let principal_point = c
            .principal_point_mm
            .map(|[x, y]| frame.principal_point_offset(&Vector2::new(x, y)));
        out.insert(
            c.name.clone(),
            FilmCamera {
                frame,
                template,
                template_path,
                principal_point,
                measure: MeasureOptions {
                    projective_from_eight: c.interior_orientation
                        == InteriorOrientationModel::Projective,
                    ..MeasureOptions::default()
                },
            },
        );
    }
    Ok(out)
}

/// What a stage reads of an image: its pixels and, for a scan, which of them hold the
/// photograph.
#[derive(Debug, Clone)]
pub struct StageImage {
    /// The pixels (a scan: resampled to its camera's frame).
    pub image: ImageF32,
    /// `None` for a photograph (every pixel usable); the film mask of a scan.
    pub usable: Option<Vec<bool>>,
}

/// How the stages see the project's images: the interior orientation of every scan.
#[derive(Debug, Clone, Default)]
pub struct ImageSource {
    scans: BTreeMap<usize, ScanTransform>,
}

impl ImageSource {
    /// The interior orientations of the project's scans (from `out/fiducials.json`); empty when
    /// no camera is film. Fails when a scan has none: the fiducials step did not run or could
    /// not orient it.
    pub fn of(project: &Project) -> Result<ImageSource, ProjectError> {
        if project.film.is_empty() {
            return Ok(ImageSource::default());
        }
        let path = project.layout().fiducials_json();
        let report: FiducialsReport = read_json(&path).map_err(|_| ProjectError::Path {
            path: path.clone(),
            message: "missing or unreadable: run `timesift fiducials` or the features stage".into(),
        })?;
        let by_name: BTreeMap<&str, usize> = project
            .images
            .iter()
            .enumerate()
            .map(|(i, im)| (im.name.as_str(), i))
            .collect();
        let mut scans = BTreeMap::new();
        for scan in &report.images {
            let Some(&i) = by_name.get(scan.image.as_str()) else {
                continue;
            };
            if let Some(m) = &scan.scan_from_frame {
                let model = match scan.model.as_str() {
                    "projective" => TransformModel::Projective,
                    "similarity" => TransformModel::Similarity,
                    _ => TransformModel::Affine,
                };
                let t = ScanTransform::from_matrix(model, Matrix3::from_fn(|r, c| m[r][c]))
                    .map_err(|e| ProjectError::Path {
                        path: path.clone(),
                        message: format!("{}: {e}", scan.image),
                    })?;
                scans.insert(i, t);
            }
        }
        let missing: Vec<&str> = project
            .images
            .iter()
            .enumerate()
            .filter(|(i, _)| project.film_camera(*i).is_some() && !scans.contains_key(i))
            .map(|(_, im)| im.name.as_str())
            .collect();
        if let Some(first) = missing.first() {
            return Err(ProjectError::Path {
                path,
                message: format!(
                    "{} scan(s) without an interior orientation, first {first}: measure their \
                     marks by hand in fiducials.csv",
                    missing.len()
                ),
            });
        }
        Ok(ImageSource { scans })
    }

    /// The interior orientation of image `i` when it is a scan.
    pub fn scan_transform(&self, i: usize) -> Option<&ScanTransform> {
        self.scans.get(&i)
    }

    /// Image `i` as the stages see it, grey (`channels` 1) or colour (3; a grey file gives 3
    /// equal channels).
    pub fn read(
        &self,
        project: &Project,
        i: usize,
        grey: bool,
    ) -> Result<StageImage, ProjectError> {
        let path = project.image_path(timesift_core::ImageId::from(i));
        let image = if grey {
            timesift_io::image::read_grey(&path)?
        } else {
            timesift_io::image::read_rgb(&path)?
        };
        let (Some(film), Some(t)) = (project.film_camera(i), self.scans.get(&i)) else {
            return Ok(StageImage {
                image,
                usable: None,
            });
        };
        let view = ImageView::new(
            image.width as usize,
            image.height as usize,
            image.channels as usize,
            &image.data,
        )
        .map_err(|e| ProjectError::Path {
            path: path.clone(),
            message: e.to_string(),
        })?;
        let frame = resample_to_frame(&view, t, &film.frame);
        Ok(StageImage {
            image: ImageF32 {
                width: frame.width as u32,
                height: frame.height as u32,
                channels: frame.channels as u32,
                data: frame.data,
            },
            usable: Some(frame.usable),
        })
    }

    /// The size of image `i` as the stages see it (a scan: its camera's frame).
    pub fn dimensions(&self, project: &Project, i: usize) -> Result<(u32, u32), ProjectError> {
        match project.film_camera(i) {
            Some(film) => Ok((film.frame.width(), film.frame.height())),
            None => Ok(timesift_io::image::dimensions(
                &project.image_path(timesift_core::ImageId::from(i)),
            )?),
        }
    }

    /// A pixel of image `i`'s file (a marker measured on a scan) in the image the stages see.
    pub fn stage_pixel(&self, i: usize, file_pixel: &Vector2<f64>) -> Vector2<f64> {
        match self.scans.get(&i) {
            Some(t) => t.frame_from_scan(file_pixel),
            None => *file_pixel,
        }
    }
}
