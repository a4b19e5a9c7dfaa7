//! The `report` stage: `out/report.html`, the page a person reads to decide whether the change
//! is real (built by [`crate::html`]). It is rebuilt on every run: it is cheap and shows the
//! latest times.

use std::path::PathBuf;

use super::{PipelineStage, Stage};
use crate::{Project, ProjectError};

/// The `report` stage.
pub(super) struct ReportStage;

impl PipelineStage for ReportStage {
    fn stage(&self) -> Stage {
        Stage::Report
    }
    fn inputs(&self, project: &Project) -> Vec<(PathBuf, Stage)> {
        // The other stages' products are optional: their sections say what is missing.
        vec![(project.layout().report_json(), Stage::Align)]
    }
    fn outputs(&self, project: &Project) -> Vec<PathBuf> {
        vec![project.layout().report_html()]
    }
    fn run(&self, project: &Project) -> Result<String, ProjectError> {
        let page = report_stage(project)?;
        let qgis = super::qgis_styles::write_qgis_files(project)?;
        Ok(format!(
            "{} written ({} kB, {} warnings); out/timesift.qgs: {} layers, each product's style \
             beside it (.qml)",
            project.layout().report_html().display(),
            page.html.len() / 1024,
            page.warnings.len(),
            qgis.layers
        ))
    }
}

/// Builds the page and writes it atomically to `out/report.html`.
pub fn report_stage(project: &Project) -> Result<crate::html::ReportPage, ProjectError> {
    let page = crate::html::build_report(project)?;
    let path = project.layout().report_html();
    timesift_io::fsutil::write_bytes_atomically(&path, page.html.as_bytes())?;
    Ok(page)
}
