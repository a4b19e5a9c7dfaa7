//! `timesift info`: what a project holds, as text for people or JSON for scripts.

use std::fmt::Write as _;

use serde::Serialize;
use timesift_core::ImageId;
use timesift_io::exif;

use crate::project::PriorSource;
use crate::{Project, ProjectError};

/// The report of `timesift info --json`.
#[derive(Debug, Clone, Serialize)]
pub struct InfoReport {
    /// Project directory.
    pub project: String,
    /// World frame.
    pub crs: String,
    /// Co-registration strategy.
    pub method: timesift_align::Method,
    /// Reference epoch.
    pub reference_epoch: String,
    /// Epochs in order.
    pub epochs: Vec<EpochInfo>,
    /// Camera groups.
    pub camera_groups: Vec<CameraGroupInfo>,
    /// Every image with its prior.
    pub images: Vec<ImageInfo>,
    /// Counts of the optional inputs.
    pub inputs: InputsInfo,
    /// Outputs present under `out/`, relative to the project.
    pub outputs: Vec<String>,
}

/// One epoch.
#[derive(Debug, Clone, Serialize)]
pub struct EpochInfo {
    /// Name.
    pub name: String,
    /// Number of images.
    pub images: usize,
    /// Camera group.
    pub camera: String,
}

/// One camera group, described from the EXIF of its first image.
#[derive(Debug, Clone, Serialize)]
pub struct CameraGroupInfo {
    /// Name.
    pub name: String,
    /// Epochs using it.
    pub epochs: Vec<String>,
    /// Image size of its first image.
    pub width: u32,
    /// Image size of its first image.
    pub height: u32,
    /// Camera make and model from EXIF.
    pub camera: Option<String>,
    /// Focal length, mm.
    pub focal_length_mm: Option<f64>,
    /// 35 mm-equivalent focal length, mm.
    pub focal_length_35mm: Option<f64>,
    /// Initial focal length in pixels from EXIF, when derivable.
    pub focal_length_px: Option<f64>,
    /// Focal length in pixels given in `[[camera]]` (a calibration), which orientation uses
    /// instead of EXIF.
    pub calibrated_focal_px: Option<f64>,
}

/// One image.
#[derive(Debug, Clone, Serialize)]
pub struct ImageInfo {
    /// Path relative to the project.
    pub name: String,
    /// Epoch.
    pub epoch: String,
    /// Camera-centre prior in the project CRS.
    pub prior: Option<PriorInfo>,
}

/// A camera-centre prior.
#[derive(Debug, Clone, Serialize)]
pub struct PriorInfo {
    /// Easting / x.
    pub x: f64,
    /// Northing / y.
    pub y: f64,
    /// Height.
    pub z: f64,
    /// Horizontal standard deviation, m.
    pub sxy: f64,
    /// Vertical standard deviation, m.
    pub sz: f64,
    /// `"gnss.csv"` or `"exif"`.
    pub source: &'static str,
}

/// Counts of the optional inputs.
#[derive(Debug, Clone, Serialize)]
pub struct InputsInfo {
    /// Ground control points.
    pub gcps: usize,
    /// Check points.
    pub checkpoints: usize,
    /// Marker observations.
    pub markers: usize,
    /// GNSS priors from the gnss file.
    pub gnss: usize,
    /// Stable areas.
    pub stable_areas: usize,
    /// Scale bars.
    pub scale_bars: usize,
}

/// Gathers the report of a loaded project (reads EXIF and image headers).
pub fn info(project: &Project) -> Result<InfoReport, ProjectError> {
    let priors = project.camera_priors()?;
    let images = project
        .images
        .iter()
        .zip(&priors)
        .map(|(im, prior)| ImageInfo {
            name: im.name.clone(),
            epoch: project.epochs[im.epoch.index()].name.clone(),
            prior: prior.map(|p| PriorInfo {
                x: p.position.x,
                y: p.position.y,
                z: p.position.z,
                sxy: p.sxy,
                sz: p.sz,
                source: match p.source {
                    PriorSource::GnssFile => "gnss.csv",
                    PriorSource::Exif => "exif",
                },
            }),
        })
        .collect();

    let mut camera_groups = Vec::new();
    for (name, epochs) in project.camera_groups() {
        let first: ImageId = project.epochs[epochs[0].index()].images[0];
        let path = project.image_path(first);
        let (width, height) = timesift_io::image::dimensions(&path)?;
        let ex = exif::read_exif(&path)?;
        let camera = match (&ex.make, &ex.model) {
            (Some(a), Some(b)) => Some(format!("{a} {b}")),
            (a, b) => a.clone().or(b.clone()),
        };
        let calibrated_focal_px = project.calibrations.get(&name).map(|g| g.focal_px);
        camera_groups.push(CameraGroupInfo {
            name,
            epochs: epochs
                .iter()
                .map(|e| project.epochs[e.index()].name.clone())
                .collect(),
            width,
            height,
            camera,
            focal_length_mm: ex.focal_length_mm,
            focal_length_35mm: ex.focal_length_35mm,
            focal_length_px: ex.focal_length_px(width, height),
            calibrated_focal_px,
        });
    }

    let epoch_names: Vec<&str> = project.epochs.iter().map(|e| e.name.as_str()).collect();
    let outputs: Vec<String> = project
        .layout()
        .outputs(&epoch_names)
        .into_iter()
        .filter(|f| f.is_file())
        .filter_map(|f| {
            f.strip_prefix(&project.dir)
                .ok()
                .map(|r| r.to_string_lossy().replace('\\', "/"))
        })
        .collect();

    Ok(InfoReport {
        project: project.dir.display().to_string(),
        crs: project.crs.to_string(),
        method: project.config.align.method,
        reference_epoch: project.epochs[project.reference_epoch.index()].name.clone(),
        epochs: project
            .epochs
            .iter()
            .map(|e| EpochInfo {
                name: e.name.clone(),
                images: e.images.len(),
                camera: e.camera_group.clone(),
            })
            .collect(),
        camera_groups,
        images,
        inputs: InputsInfo {
            gcps: project.gcps.len(),
            checkpoints: project.checkpoints.len(),
            markers: project.markers.len(),
            gnss: project.gnss.len(),
            stable_areas: project.stable_areas.len(),
            scale_bars: project.scale_bars.len(),
        },
        outputs,
    })
}

impl InfoReport {
    /// The report as text for people.
    pub fn to_text(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(s, "project   {}", self.project);
        let _ = writeln!(s, "crs       {}", self.crs);
        let _ = writeln!(
            s,
            "method    {} (reference epoch {})",
            self.method, self.reference_epoch
        );
        let _ = writeln!(s, "\nepochs");
        for e in &self.epochs {
            let with_prior = self
                .images
                .iter()
                .filter(|i| i.epoch == e.name && i.prior.is_some())
                .count();
            let _ = writeln!(
                s,
                "  {:<20} {:>5} images  camera {:<16} {} with position prior",
                e.name, e.images, e.camera, with_prior
            );
        }
        let _ = writeln!(s, "\ncamera groups");
        for c in &self.camera_groups {
            let focal = match (
                c.calibrated_focal_px,
                c.focal_length_mm,
                c.focal_length_35mm,
                c.focal_length_px,
            ) {
                (Some(given), ..) => format!("f = {given:.1} px (given in project.toml)"),
                (None, mm, eq, Some(px)) => {
                    let parts: Vec<String> = mm
                        .map(|v| format!("{v} mm"))
                        .into_iter()
                        .chain(eq.map(|v| format!("{v} mm equiv.")))
                        .collect();
                    if parts.is_empty() {
                        format!("f ≈ {px:.0} px")
                    } else {
                        format!("f ≈ {px:.0} px ({})", parts.join(", "))
                    }
                }
                _ => "focal length unknown (no EXIF)".to_string(),
            };
            let _ = writeln!(
                s,
                "  {:<20} {}x{}  {}  {}  epochs: {}",
                c.name,
                c.width,
                c.height,
                c.camera.as_deref().unwrap_or("unknown camera"),
                focal,
                c.epochs.join(", ")
            );
        }
        let _ = writeln!(s, "\nimages (camera-centre priors in {})", self.crs);
        for i in &self.images {
            match &i.prior {
                Some(p) => {
                    let _ = writeln!(
                        s,
                        "  {:<40} {:>14.3} {:>14.3} {:>9.3}  ±{}/{} m ({})",
                        i.name, p.x, p.y, p.z, p.sxy, p.sz, p.source
                    );
                }
                None => {
                    let _ = writeln!(s, "  {:<40} no prior", i.name);
                }
            }
        }
        let n = &self.inputs;
        let _ = writeln!(
            s,
            "\ninputs    {} GCPs, {} check points, {} markers, {} GNSS priors, {} stable areas, \
             {} scale bars",
            n.gcps, n.checkpoints, n.markers, n.gnss, n.stable_areas, n.scale_bars
        );
        if self.outputs.is_empty() {
            let _ = writeln!(s, "outputs   none yet");
        } else {
            let _ = writeln!(s, "outputs");
            for o in &self.outputs {
                let _ = writeln!(s, "  {o}");
            }
        }
        s
    }
}
