//! What `timesift-eval` needs of a project, read the root's way: the project's control and
//! epochs ([`project_truth`]) and the align stage's report per epoch ([`oriented_epochs`]). The
//! comparisons themselves are `timesift-eval`'s; `timesift demo`, the benches and the tests meet
//! it here.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use nalgebra::Vector3;
use timesift_eval::{OrientedEpoch, ProjectTruth};

use crate::config::ImageKind;
use crate::report::{AlignReport, EpochOrientation, read_json};
use crate::{Project, ProjectError};

/// The project's epochs, control and stable areas as the comparisons with the truth take them.
pub fn project_truth(project: &Project) -> Result<ProjectTruth<'_>, ProjectError> {
    let stable_polygons = match crate::stages::stable_file(project) {
        Some(path) => crate::commands::compare::read_polygons(&path)?,
        None => Vec::new(),
    };
    Ok(ProjectTruth {
        layout: project.layout(),
        epochs: project.epochs.iter().map(|e| e.name.as_str()).collect(),
        reference_epoch: &project.epochs[project.reference_epoch.index()].name,
        film_epochs: (0..project.epochs.len())
            .filter(|&e| project.image_kind(e) == ImageKind::FilmScan)
            .map(|e| project.epochs[e].name.as_str())
            .collect::<BTreeSet<_>>(),
        checkpoints: &project.checkpoints,
        gcps: &project.gcps,
        markers: &project.markers,
        stable_polygons,
    })
}

/// Each epoch of the align stage's report in `out` (`report.json`), as the comparisons take it.
pub fn oriented_epochs(out: &Path) -> Result<BTreeMap<String, OrientedEpoch>, ProjectError> {
    let report: AlignReport = read_json(&out.join("report.json"))?;
    Ok(report
        .epochs
        .iter()
        .map(|(name, epoch)| (name.clone(), oriented_epoch(epoch)))
        .collect())
}

fn oriented_epoch(epoch: &EpochOrientation) -> OrientedEpoch {
    OrientedEpoch {
        images_given: epoch.images_given,
        images_oriented: epoch.images_oriented,
        rms_px: epoch.rms_reprojection_px,
        observations: epoch.observations,
        check_residuals: epoch
            .check_points
            .points
            .iter()
            .filter_map(|p| Some((p.name.clone(), Vector3::from(p.vector()?))))
            .collect(),
        check_markers_rmse_m: epoch.check_points.markers_rmse.map(|r| [r.de, r.dn, r.dh]),
        inter_epoch_tie_points: epoch.inter_epoch_tie_points,
        gnss_offset: epoch.gnss_offset.map(|o| (o.offset, o.std)),
        datum_tilt_sigma_mm_per_m: epoch.datum_tilt.map(|t| t.sigma_max_mm_per_m),
    }
}
