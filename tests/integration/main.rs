//! The root package's integration tests, one test binary: each module was a binary of its own,
//! and each of those linked the whole of timesift again (a minute of CPU on a clean build).

mod berlin;
mod berlin_align;
mod cli;
mod cluster;
mod common;
mod compare;
mod degenerate;
mod dem_command;
mod downstream;
mod faults;
mod features;
mod film;
mod guide_examples;
mod guide_reference;
mod huge_claims;
mod raster_stacking;
mod reference_dem;
mod report_html;
mod run_align;
mod run_all;
mod run_dense;
mod run_match;
mod run_raster;
mod synth;
mod tidy;
mod tidy_sources;
