//! `timesift fiducials DIR`: measures the fiducial marks of every scan of a film camera (as the
//! features stage does before it extracts) and tells a person how it went: a table per scan,
//! the marks that were not found or were rejected, and where the results are.

use std::fmt::Write as _;

use crate::stages::{FiducialsOutcome, fiducials_stage};
use crate::{Project, ProjectError};

/// Measures (or reads, when up to date) every scan's marks; fails when no camera of the project
/// lists fiducial marks.
pub fn fiducials(project: &Project) -> Result<FiducialsOutcome, ProjectError> {
    fiducials_stage(project)?.ok_or_else(|| {
        ProjectError::config(
            project.layout().project_toml(),
            "camera",
            "no [[camera]] lists fiducial marks ([camera.fiducials]): no image is a film scan",
        )
    })
}

/// Fails, naming the first, when a scan has no interior orientation (its marks must then be
/// measured by hand in `fiducials.csv`).
pub fn all_oriented(outcome: &FiducialsOutcome) -> Result<(), ProjectError> {
    let failed: Vec<_> = outcome
        .report
        .images
        .iter()
        .filter(|s| s.error.is_some())
        .collect();
    match failed.first() {
        None => Ok(()),
        Some(first) => Err(ProjectError::Stage {
            stage: "fiducials",
            message: format!(
                "{} scans not oriented; first {}: {} (measure its marks by hand in fiducials.csv)",
                failed.len(),
                first.image,
                first.error.as_deref().unwrap_or("")
            ),
        }),
    }
}

/// The summary a person reads: one line per scan (marks used of all, model, RMS and largest
/// residual, scale and rotation of the scan), then every warning and error naming its scan and
/// mark, then the per-mark RMS of residuals over all scans.
pub fn summary_table(outcome: &FiducialsOutcome) -> String {
    let report = &outcome.report;
    let mut text = String::new();
    let width = report
        .images
        .iter()
        .map(|s| s.image.chars().count())
        .max()
        .unwrap_or(5)
        .max(5);
    let _ = writeln!(
        text,
        "{:<width$}  marks  model       RMS px  max px  scale (×1e-4)   rotation°",
        "scan"
    );
    for s in &report.images {
        let used = s
            .marks
            .iter()
            .filter(|m| m.status == "measured" || m.status == "given")
            .count();
        let max = s
            .marks
            .iter()
            .filter(|m| m.status == "measured" || m.status == "given")
            .filter_map(|m| m.residual_px)
            .fold(0.0f64, f64::max);
        match (s.rms_px, s.scales, s.rotation_deg) {
            (Some(rms), Some([a, b]), Some(rot)) => {
                let _ = writeln!(
                    text,
                    "{:<width$}  {used:>2}/{:<2}  {:<10}  {rms:>6.3}  {max:>6.3}  {:>+6.1} {:>+6.1}  {rot:>+9.4}",
                    s.image,
                    s.marks.len(),
                    s.model,
                    (a - 1.0) * 1e4,
                    (b - 1.0) * 1e4,
                );
            }
            _ => {
                let _ = writeln!(
                    text,
                    "{:<width$}  {used:>2}/{:<2}  not oriented: {}",
                    s.image,
                    s.marks.len(),
                    s.error.as_deref().unwrap_or("")
                );
            }
        }
    }
    for s in &report.images {
        for w in &s.warnings {
            let _ = writeln!(text, "warning: {}: {w}", s.image);
        }
    }
    let mut per_mark: std::collections::BTreeMap<(String, String), (f64, usize)> =
        Default::default();
    for s in &report.images {
        for m in &s.marks {
            if let (Some(r), true) = (m.residual_px, m.status == "measured" || m.status == "given")
            {
                let e = per_mark
                    .entry((s.camera.clone(), m.mark.clone()))
                    .or_default();
                e.0 += r * r;
                e.1 += 1;
            }
        }
    }
    if !per_mark.is_empty() {
        let _ = writeln!(text, "residual RMS per mark over the scans (px):");
        let mut camera = String::new();
        for ((c, mark), (sum, n)) in &per_mark {
            if *c != camera {
                if !camera.is_empty() {
                    text.push('\n');
                }
                let _ = write!(text, "  {c}:");
                camera = c.clone();
            }
            let _ = write!(text, " {mark} {:.3}", (sum / *n as f64).sqrt());
        }
        text.push('\n');
    }
    text
}
