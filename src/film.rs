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

/// A camera's radial terms (k1, k2, k3) from its certificate's curve (`distortion_um`), when
/// given; the message of what is wrong with it otherwise.
pub(crate) fn certificate_radial(
    c: &crate::config::CameraConfig,
) -> Result<Option<[f64; 3]>, String> {
    let (Some(curve), focal_mm) = (&c.distortion_um, c.focal_mm) else {
        return Ok(None);
    };
    let focal_mm = focal_mm.ok_or("needs focal_mm and pixel_mm: the curve is in millimetres")?;
    let fit = timesift_film::radial_from_certificate(curve, focal_mm).map_err(|e| e.to_string())?;
    tracing::info!(
        camera = %c.name,
        k = ?fit.k,
        rms_um = fit.rms_um,
        "radial distortion from the certificate's curve"
    );
    Ok(Some(fit.k))
}

/// A `[[camera]] mask`: which pixels of a camera group's images (as the stages see them) may
/// give keypoints and depths.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraMask {
    /// The file.
    pub path: PathBuf,
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Row-major, `true` where usable.
    pub usable: Vec<bool>,
}

/// The `[[camera]] mask` images, by camera group, read and checked.
pub(crate) fn camera_masks(
    dir: &Path,
    cfg_path: &Path,
    config: &ProjectConfig,
) -> Result<BTreeMap<String, CameraMask>, ProjectError> {
    let mut out = BTreeMap::new();
    for (i, c) in config.cameras.iter().enumerate() {
        let Some(name) = &c.mask else {
            continue;
        };
        let path = dir.join(name);
        if !path.is_file() {
            return Err(ProjectError::config(
                cfg_path,
                format!("camera[{i}].mask"),
                format!("file \"{name}\" does not exist"),
            ));
        }
        let image = timesift_io::image::read_grey(&path)?;
        out.insert(
            c.name.clone(),
            CameraMask {
                path,
                width: image.width,
                height: image.height,
                usable: image.data.iter().map(|&v| v > 0.0).collect(),
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
    /// `None` when every pixel is usable; else the film mask of a scan and the camera's
    /// `[[camera]] mask`.
    pub usable: Option<Vec<bool>>,
}

impl StageImage {
    /// The pixels, and the film and camera masks as dense matching takes them (`None`: every
    /// pixel usable).
    pub fn into_dense_parts(self) -> (ImageF32, Option<timesift_dense::Mask>) {
        let (width, height) = (self.image.width as usize, self.image.height as usize);
        let mask = self.usable.map(|usable| timesift_dense::Mask {
            width,
            height,
            usable,
        });
        (self.image, mask)
    }
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
        let source = ImageSource::of_report(project, &report)?;
        let scans = &source.scans;
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
        Ok(source)
    }

    /// The interior orientations a fiducials report gives (scans without one are left out).
    pub(crate) fn of_report(
        project: &Project,
        report: &FiducialsReport,
    ) -> Result<ImageSource, ProjectError> {
        let path = project.layout().fiducials_json();
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
        Ok(ImageSource { scans })
    }

    /// A fingerprint of how the stages see the images (the scans' interior orientations, the
    /// camera masks), for the caches of the stages that read pixels; empty when images are read
    /// as they are.
    pub fn fingerprint(&self, project: &Project) -> String {
        if self.scans.is_empty() && project.camera_masks.is_empty() {
            return String::new();
        }
        let mut hash = crate::stages::Fnv1a::new();
        for (i, t) in &self.scans {
            hash.write(&i.to_le_bytes());
            for v in t.scan_from_frame_matrix().iter() {
                hash.write_f64(*v);
            }
        }
        for (group, mask) in &project.camera_masks {
            hash.write(group.as_bytes());
            hash.write(&mask.width.to_le_bytes());
            hash.write(&mask.height.to_le_bytes());
            hash.write(&mask.usable.iter().map(|&u| u as u8).collect::<Vec<u8>>());
        }
        hash.hex()
    }

    /// Whether image `i` is read as its file is (not a scan, no camera mask).
    pub fn as_is(&self, project: &Project, i: usize) -> bool {
        let group = &project.epochs[project.images[i].epoch.index()].camera_group;
        !self.scans.contains_key(&i) && !project.camera_masks.contains_key(group)
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
        let seen = match (project.film_camera(i), self.scans.get(&i)) {
            (Some(film), Some(t)) => resampled(&path, &image, film, t)?,
            _ => StageImage {
                image,
                usable: None,
            },
        };
        let group = &project.epochs[project.images[i].epoch.index()].camera_group;
        match project.camera_masks.get(group) {
            None => Ok(seen),
            Some(mask) => with_camera_mask(&path, seen, mask),
        }
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

/// A scan resampled to its camera's frame, with the film mask.
fn resampled(
    path: &Path,
    scan: &ImageF32,
    film: &FilmCamera,
    transform: &ScanTransform,
) -> Result<StageImage, ProjectError> {
    let view = ImageView::new(
        scan.width as usize,
        scan.height as usize,
        scan.channels as usize,
        &scan.data,
    )
    .map_err(|e| ProjectError::Path {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    let frame = resample_to_frame(&view, transform, &film.frame);
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

/// The image with its camera's `[[camera]] mask` applied; a mask of another size is an error
/// naming both.
fn with_camera_mask(
    path: &Path,
    mut seen: StageImage,
    mask: &CameraMask,
) -> Result<StageImage, ProjectError> {
    if (mask.width, mask.height) != (seen.image.width, seen.image.height) {
        return Err(ProjectError::Path {
            path: mask.path.clone(),
            message: format!(
                "the mask is {} × {} pixels but {} is {} × {} as the stages see it",
                mask.width,
                mask.height,
                path.display(),
                seen.image.width,
                seen.image.height
            ),
        });
    }
    let usable = seen
        .usable
        .get_or_insert_with(|| vec![true; mask.usable.len()]);
    for (u, &m) in usable.iter_mut().zip(&mask.usable) {
        *u &= m;
    }
    Ok(seen)
}
