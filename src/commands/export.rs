//! `timesift export DIR --format metashape|colmap|opensfm [--out FOLDER]`: the orientation
//! (`out/cameras.json`) and the sparse points (`out/colmap/`) in the formats of the tools users
//! already have. Default folder: `out/export/<format>/`.
//!
//! Georeferenced blocks go to Metashape and OpenSfM in a topocentric frame around the cameras'
//! mean centre (see `timesift_io::topocentric`), so they land where they are rather than rotated
//! by the grid's convergence; COLMAP gets the project's own world frame, as `out/colmap/`.

use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use timesift_io::cameras_json::{Reconstruction, read_cameras_json};
use timesift_io::colmap::{ColmapModel, read_colmap_text, write_colmap_text};
use timesift_io::topocentric::ExportFrame;

use crate::{Project, ProjectError};

/// A format `timesift export` writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ExportFormat {
    /// Agisoft Metashape camera XML (`cameras.xml`).
    Metashape,
    /// COLMAP text model (`cameras.txt`, `images.txt`, `points3D.txt`).
    Colmap,
    /// OpenSfM / OpenDroneMap `reconstruction.json` (+ `reference_lla.json`).
    Opensfm,
}

impl ExportFormat {
    /// The format's name on the command line and its default folder.
    pub fn name(self) -> &'static str {
        match self {
            ExportFormat::Metashape => "metashape",
            ExportFormat::Colmap => "colmap",
            ExportFormat::Opensfm => "opensfm",
        }
    }
}

/// Writes the export; returns the files written.
pub fn export(
    project: &Project,
    format: ExportFormat,
    out: Option<&Path>,
) -> Result<Vec<PathBuf>, ProjectError> {
    let layout = project.layout();
    let folder = out
        .map(Path::to_path_buf)
        .unwrap_or_else(|| layout.export_dir(format.name()));
    let cameras = layout.cameras_json();
    if !cameras.is_file() {
        return Err(ProjectError::Path {
            path: cameras,
            message: "missing; run the align stage first (timesift run DIR --to align)".into(),
        });
    }
    let recon = read_cameras_json(&cameras)?;
    match format {
        ExportFormat::Colmap => {
            write_colmap_text(&folder, &read_colmap_text(&layout.colmap_dir())?)?;
            Ok(["cameras.txt", "images.txt", "points3D.txt"]
                .iter()
                .map(|f| folder.join(f))
                .collect())
        }
        ExportFormat::Opensfm => {
            let frame = export_frame(project, &recon)?;
            let model = read_colmap_text(&layout.colmap_dir())?;
            Ok(timesift_io::opensfm::write_opensfm(
                &folder,
                &recon,
                &sparse_points(&model),
                &frame,
            )?)
        }
        ExportFormat::Metashape => {
            let frame = export_frame(project, &recon)?;
            let path = folder.join("cameras.xml");
            timesift_io::metashape::write_metashape_xml(&path, &recon, &frame, project.crs.wkt())?;
            Ok(vec![path])
        }
    }
}

/// The topocentric frame around the oriented cameras' mean centre (the world frame when local).
pub fn export_frame(
    project: &Project,
    recon: &Reconstruction,
) -> Result<ExportFrame, ProjectError> {
    let centres: Vec<Vector3<f64>> = recon
        .images
        .iter()
        .filter_map(|i| i.pose.as_ref().map(|p| p.center()))
        .collect();
    if centres.is_empty() {
        return Err(ProjectError::Path {
            path: project.layout().cameras_json(),
            message: "no oriented image: nothing to export".into(),
        });
    }
    let mean = centres.iter().sum::<Vector3<f64>>() / centres.len() as f64;
    Ok(ExportFrame::new(project.crs, mean)?)
}

/// The sparse points with their colours.
pub fn sparse_points(model: &ColmapModel) -> Vec<(Vector3<f64>, [u8; 3])> {
    model.points.values().map(|p| (p.xyz, p.rgb)).collect()
}
