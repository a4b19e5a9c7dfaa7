//! Measures a project's outputs against the truth a synthetic scene carries (`truth/`, written by
//! `timesift-synth`): the orientation at the check points and camera centres
//! ([`accuracy`]), DEMs, orthomosaic targets and region volumes ([`products`]), and an
//! orientation made from the truth so that the stages after `align` can be judged alone
//! ([`true_scene`]). `timesift demo`, the benches of `cargo xtask` and the tests use it.
//!
//! Invariants: reads outputs and truth only through `timesift-io`, and writes only the
//! stand-ins of [`true_scene`]; knows the project directory's paths (`timesift_io::layout`)
//! but not `project.toml` nor the stages' reports: the caller hands over what it read
//! ([`ProjectTruth`], [`OrientedEpoch`]); every failure is an [`EvalError`] naming the file.

#![warn(missing_docs, unnameable_types)]

pub mod accuracy;
mod error;
pub mod products;
pub mod true_scene;

use std::collections::BTreeSet;

use timesift_io::csv_inputs::{ControlPoint, Marker};
use timesift_io::layout::Layout;
use timesift_io::wkt::Polygon;

pub use accuracy::OrientedEpoch;
pub use error::EvalError;

/// What the comparisons need of a synthetic project, from its `project.toml` and inputs.
#[derive(Debug, Clone)]
pub struct ProjectTruth<'a> {
    /// The project directory's paths (its `truth/` among them).
    pub layout: Layout,
    /// The epochs' names, in order.
    pub epochs: Vec<&'a str>,
    /// The reference epoch's name.
    pub reference_epoch: &'a str,
    /// Epochs whose images are film scans (their markers are measured on the scans).
    pub film_epochs: BTreeSet<&'a str>,
    /// Check points.
    pub checkpoints: &'a [ControlPoint],
    /// Ground control points.
    pub gcps: &'a [ControlPoint],
    /// Marker measurements.
    pub markers: &'a [Marker],
    /// The stable areas' polygons (for the volumes' uncertainty); empty without.
    pub stable_polygons: Vec<Polygon>,
}

/// `a / b / c` with `digits` decimals, or a dash: how the tables print a per-axis figure.
pub fn triple(v: Option<[f64; 3]>, digits: usize) -> String {
    v.map_or("–".to_string(), |v| {
        format!("{:.d$} / {:.d$} / {:.d$}", v[0], v[1], v[2], d = digits)
    })
}
