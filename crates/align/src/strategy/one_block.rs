//! The single-block adjustment that `timesift` and `msfm` share once every epoch's images are in
//! one reconstruction: inter-epoch tie points on surfaces that moved split by epoch, the block
//! georeferenced, then tied again only through stable ground (given, or found from the block's
//! own ties).

use crate::AlignError;
use crate::changed::detect_changed_ground;
use crate::georef::{Datum, Diagnostics, Georeferenced, georeference};
use crate::model::Reconstruction;
use crate::moved::{Separated, separate_moved_points};
use crate::options::{ChangeDetection, SfmOptions};
use crate::surface::SurfaceComparison;

use super::block::Block;
use super::similarity::median_ground_pixel;

/// Most rounds of change detection: each takes the most significant regions left and adjusts
/// the block without their ties, which shows what is left more clearly.
const CHANGE_DETECTION_ROUNDS: usize = 6;
/// Rounds of surface ties: the second compares the points once the first has removed most of
/// the epoch's offset and tilt, so that fewer points on changed ground pass.
const SURFACE_ROUNDS: usize = 2;

/// The components of the whole block (largest first) adjusted and georeferenced as one.
pub(crate) fn adjust_as_one_block(
    block: &Block,
    components: Vec<Reconstruction>,
    options: &SfmOptions,
) -> Result<Georeferenced, AlignError> {
    let mut separated = separate_moved_points(
        &block.sfm,
        components,
        &block.epoch_of,
        block.reference,
        options,
    )?;
    let components = std::mem::take(&mut separated.components);
    let placed = georeference(&separated.input, components, &block.ground, options)?;
    let placed = tie_on_stable_ground(block, &mut separated, placed, options)?;
    let mut placed = tie_by_surface(block, &separated, placed, options)?;
    placed.diagnostics.moved_ties_split = separated.split;
    separated.restore_track_ids(&mut placed.reconstruction);
    Ok(placed)
}

/// With stable ground given, the inter-epoch tie points of the georeferenced block that lie
/// off it are split by epoch ([`Separated::split_unstable`]) and the block is adjusted again:
/// only stable ground ties the epochs. Without it, and with [`ChangeDetection::Regional`], the
/// changed ground is found from the block's own ties ([`detect_changed_ground`]), the same way,
/// round after round until none is found. Otherwise `placed` as it is.
fn tie_on_stable_ground(
    block: &Block,
    separated: &mut Separated,
    mut placed: Georeferenced,
    options: &SfmOptions,
) -> Result<Georeferenced, AlignError> {
    let detect = options.change_detection == ChangeDetection::Regional;
    if block.stable_ground.is_none() && !detect {
        return Ok(placed);
    }
    if placed.datum == Datum::Local {
        // Without a datum the block's frame is not the stable ground's, and has no "up".
        tracing::warn!("stable ground cannot select inter-epoch ties in an ungeoreferenced block");
        return Ok(placed);
    }
    let rounds = if block.stable_ground.is_some() {
        1
    } else {
        CHANGE_DETECTION_ROUNDS
    };
    let (mut total, mut regions) = (0, 0);
    for _ in 0..rounds {
        let found;
        let stable = match &block.stable_ground {
            Some(stable) => stable,
            None => {
                // σ of one observation per axis, from the block's RMS (a 2-D norm).
                let noise_px = (placed.rms_px / std::f64::consts::SQRT_2).max(0.1);
                let Some(detected) = detect_changed_ground(
                    &separated.input,
                    &placed.reconstruction,
                    &block.epoch_of,
                    block.reference,
                    noise_px,
                ) else {
                    break;
                };
                regions += detected.regions_changed;
                found = detected;
                &found.stable
            }
        };
        let split = separated.split_unstable(
            &mut placed.reconstruction,
            &block.epoch_of,
            block.reference,
            stable,
        );
        tracing::info!(
            split,
            "inter-epoch tie points off the stable ground split by epoch"
        );
        if split == 0 {
            break;
        }
        total += split;
        let mut again = georeference(
            &separated.input,
            vec![placed.reconstruction],
            &block.ground,
            options,
        )?;
        again.diagnostics.dropped_components += placed.diagnostics.dropped_components;
        placed = again;
    }
    placed.diagnostics.unstable_ties_split = total;
    placed.diagnostics.changed_regions = regions;
    Ok(placed)
}

/// With [`SfmOptions::surface_ties`], the later epochs' own tie points get height observations
/// from the reference epoch's surface (module `surface`) and the block is adjusted again with
/// them; either way, each later epoch's fit against that surface in the final block
/// ([`Georeferenced::surface_fits`]). A block without a datum has no "up" to compare heights
/// along, and is returned as it is.
fn tie_by_surface(
    block: &Block,
    separated: &Separated,
    placed: Georeferenced,
    options: &SfmOptions,
) -> Result<Georeferenced, AlignError> {
    let epochs = block.epoch_names.len();
    if placed.datum == Datum::Local || epochs < 2 {
        return Ok(placed);
    }
    let stable = block.stable_ground_for(&placed);
    let ground_px = median_ground_pixel(&placed.reconstruction);
    let mut placed = placed;
    let comparison = SurfaceComparison {
        epoch_of: &block.epoch_of,
        reference: block.reference,
        epochs,
        stable,
        ground_px,
    };
    if options.surface_ties {
        for round in 0..SURFACE_ROUNDS {
            let (mut heights, before) = comparison.heights(&placed.reconstruction);
            for fit in &before {
                let (tilt, sigma) = fit.tilt_mm_per_m();
                tracing::info!(
                    round,
                    epoch = %block.epoch_names[fit.epoch],
                    kept = fit.kept,
                    compared = fit.compared,
                    sigma = fit.sigma,
                    offset = fit.plane[0],
                    tilt_mm_per_m = tilt,
                    tilt_sigma = sigma,
                    "an epoch's tie points against the reference epoch's surface"
                );
            }
            if heights.is_empty() {
                break;
            }
            heights.sort_by_key(|h| h.track);
            let geo = crate::georef::GeoreferenceInput {
                surface_heights: heights,
                ..block.ground.clone()
            };
            let count = geo.surface_heights.len();
            let mut again =
                georeference(&separated.input, vec![placed.reconstruction], &geo, options)?;
            let diagnostics = placed.diagnostics;
            again.diagnostics = Diagnostics {
                surface_heights: count,
                dropped_components: diagnostics.dropped_components
                    + again.diagnostics.dropped_components,
                ..diagnostics
            };
            placed = again;
        }
    }
    placed.surface_fits = comparison.fits(&placed.reconstruction);
    Ok(placed)
}
