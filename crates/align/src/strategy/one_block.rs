//! The single-block adjustment that `timesift` and `msfm` share once every epoch's images are in
//! one reconstruction: inter-epoch tie points on surfaces that moved split by epoch, the block
//! georeferenced, then tied again only through stable ground (given, or found from the block's
//! own ties).

use crate::AlignError;
use crate::changed::detect_changed_ground;
use crate::georef::{Datum, Diagnostics, Georeferenced, georeference, georeference_settled};
use crate::model::Reconstruction;
use crate::moved::{Separated, separate_moved_points};
use crate::options::{ChangeDetection, SfmOptions};
use crate::surface::{EpochSurface, SurfaceComparison};

use super::block::Block;
use super::similarity::median_ground_pixel;

/// Most rounds of change detection: each takes the most significant regions left and adjusts
/// the block without their ties, which shows what is left more clearly.
const CHANGE_DETECTION_ROUNDS: usize = 6;
/// Rounds of surface ties: the second compares the points once the first has removed most of
/// the epoch's offset and tilt, so that fewer points on changed ground pass.
const SURFACE_ROUNDS: usize = 2;
/// Rounds against a reference DEM: each samples it again where the points moved to, and a
/// film block without control may start metres off it.
const DEM_ROUNDS: usize = 4;

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
        // The same images, priors and control, fewer inter-epoch ties: the focal lengths stay
        // as the first georeferencing settled them.
        let mut again = georeference_settled(
            &separated.input,
            vec![placed.reconstruction],
            &block.ground,
            options,
            Some(&placed.focal_held),
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
/// ([`Georeferenced::surface_fits`]). With a reference DEM, every epoch's points are held to
/// it instead, whatever `surface_ties` says. A block without a datum has no "up" to compare
/// heights along, and is returned as it is (with a reference DEM, that is an error).
fn tie_by_surface(
    block: &Block,
    separated: &Separated,
    placed: Georeferenced,
    options: &SfmOptions,
) -> Result<Georeferenced, AlignError> {
    let epochs = block.epoch_names.len();
    let dem = block.ground.reference_dem.as_deref();
    if dem.is_some() && placed.datum == Datum::Local {
        return Err(AlignError::Georeferencing(
            "a reference DEM needs a datum to start from: control points (gcps.csv) or camera \
             centre priors (gnss.csv, or EXIF GPS) to within some metres; the block has neither"
                .into(),
        ));
    }
    if let Some(dem) = dem {
        return tie_to_dem(block, separated, placed, options, dem);
    }
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
        dem: None,
    };
    if options.surface_ties {
        // Which epochs are held: decided on the first comparison, before any is.
        let mut held_epochs: Option<Vec<usize>> = None;
        for round in 0..SURFACE_ROUNDS {
            let compared = comparison.heights(&placed.reconstruction);
            let held_epochs = held_epochs.get_or_insert_with(|| {
                let covariance = placed.set_motion_covariance.as_ref();
                compared
                    .iter()
                    .map(|c| &c.fit)
                    .filter(|f| {
                        significant(f, ground_px)
                            && (stable.is_some()
                                || plausible(covariance, &block.epoch_names[f.epoch], f))
                    })
                    .map(|f| f.epoch)
                    .collect()
            });
            let mut heights: Vec<_> = compared
                .iter()
                .filter(|c| held_epochs.contains(&c.fit.epoch))
                .flat_map(|c| c.held.iter().copied())
                .collect();
            log_fits(block, round, &compared, "the reference epoch's surface");
            if heights.is_empty() {
                break;
            }
            heights.sort_by_key(|h| h.track);
            let (adjusted, held) = adjust_with_heights(block, separated, placed, heights, options)?;
            placed = Georeferenced {
                surface_held: held,
                ..adjusted
            };
        }
    }
    placed.surface_fits = comparison.fits(&placed.reconstruction);
    Ok(placed)
}

/// Every epoch's tie points on stable ground (given, or where they meet the DEM) held to the
/// reference DEM ([`DEM_ROUNDS`] adjustments, each sampling it again), and each epoch's fit
/// against it in the final block. No epoch is left out for a small or a large miss: the DEM
/// was given to be the datum.
fn tie_to_dem(
    block: &Block,
    separated: &Separated,
    mut placed: Georeferenced,
    options: &SfmOptions,
    dem: &crate::ReferenceDem,
) -> Result<Georeferenced, AlignError> {
    let comparison = SurfaceComparison {
        epoch_of: &block.epoch_of,
        reference: block.reference,
        epochs: block.epoch_names.len(),
        stable: block.stable_ground_for(&placed),
        ground_px: median_ground_pixel(&placed.reconstruction),
        dem: Some(dem),
    };
    for round in 0..DEM_ROUNDS {
        let compared = comparison.heights(&placed.reconstruction);
        log_fits(block, round, &compared, "the reference DEM");
        let mut heights: Vec<_> = compared.into_iter().flat_map(|c| c.held).collect();
        // A point seen in several epochs is compared in each, and held once.
        heights.sort_by_key(|h| h.track);
        heights.dedup_by_key(|h| h.track);
        if heights.is_empty() {
            tracing::warn!(
                "no epoch has enough tie points on stable ground where the reference DEM has \
                 heights: the block is not held to it"
            );
            break;
        }
        let (adjusted, held) = adjust_with_heights(block, separated, placed, heights, options)?;
        placed = Georeferenced {
            dem_heights: held,
            ..adjusted
        };
    }
    placed.surface_fits = comparison.fits(&placed.reconstruction);
    placed.fits_against_dem = true;
    Ok(placed)
}

/// Each epoch's fit of one round, logged.
fn log_fits(block: &Block, round: usize, compared: &[EpochSurface], against: &str) {
    for fit in compared.iter().map(|c| &c.fit) {
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
            against,
            "an epoch's tie points against a reference surface"
        );
    }
}

/// The block georeferenced again with `heights` (sorted by track) on its tie points; and the
/// heights back.
fn adjust_with_heights(
    block: &Block,
    separated: &Separated,
    placed: Georeferenced,
    heights: Vec<crate::SurfaceHeight>,
    options: &SfmOptions,
) -> Result<(Georeferenced, Vec<crate::SurfaceHeight>), AlignError> {
    let geo = crate::georef::GeoreferenceInput {
        surface_heights: heights,
        ..block.ground.clone()
    };
    let count = geo.surface_heights.len();
    let mut again = georeference(&separated.input, vec![placed.reconstruction], &geo, options)?;
    let diagnostics = placed.diagnostics;
    again.diagnostics = Diagnostics {
        surface_heights: count,
        dropped_components: diagnostics.dropped_components + again.diagnostics.dropped_components,
        ..diagnostics
    };
    Ok((again, geo.surface_heights))
}

/// How many σ of the fit's own an epoch's offset or tilt against the reference surface must
/// reach to be worth holding: below, there is nothing to correct, and the held points would
/// only add the surface's noise and any change below the bound (on `synth shore` without its
/// stable areas, misses of 0.37 ± 0.32 mm/m held anyway moved three epochs' check dH RMSE from
/// 0.117, 0.115, 0.156 to 0.131, 0.135, 0.163 m).
const SIGNIFICANT_SIGMAS: f64 = 3.0;

/// Smallest miss worth holding, ground pixels: the offset, or the tilt's rise at the compared
/// points' farthest from their centroid. Below, re-adjusting the block moves it by as much
/// through its new outlier bounds (on `synth shore`, a held epoch off by 1 cm, 3 σ, moved the
/// other epochs' check dH RMSE by up to 3 cm).
const MATERIAL_GROUND_PX: f64 = 0.5;

/// Whether an epoch's offset or tilt against the reference surface is beyond
/// [`SIGNIFICANT_SIGMAS`] of its own σ and [`MATERIAL_GROUND_PX`] in size.
fn significant(fit: &crate::surface::SurfaceFit, ground_px: f64) -> bool {
    let (tilt, tilt_sigma) = fit.tilt_mm_per_m();
    let reach = fit
        .unchanged
        .iter()
        .map(|p| (p[0] - fit.centroid[0]).hypot(p[1] - fit.centroid[1]))
        .fold(0.0, f64::max);
    let material = MATERIAL_GROUND_PX * ground_px;
    (fit.plane[0].abs() > SIGNIFICANT_SIGMAS * fit.plane_std[0] && fit.plane[0].abs() > material)
        || (tilt > SIGNIFICANT_SIGMAS * tilt_sigma && 1e-3 * tilt * reach > material)
}

/// How many σ of what the block allows an epoch's offset or tilt against the reference surface
/// may reach and still be taken for a misorientation the surface ties correct. Beyond, without
/// stable ground given, the epoch's ground changed (a glacier thinned by metres: on `synth
/// glacier` with the stable areas hidden its later epochs missed by −3.6 and −4.7 m, and held
/// to the surface anyway they dragged the whole block 7 m up), and nothing is held.
const PLAUSIBLE_SIGMAS: f64 = 10.0;

/// Whether an epoch's offset and tilt against the reference surface are within
/// [`PLAUSIBLE_SIGMAS`] of the σ the block's covariance gives its rigid motion (vertical
/// translation; tilt about the loosest axis); without that covariance, no.
fn plausible(
    covariance: Option<&nalgebra::DMatrix<f64>>,
    name: &str,
    fit: &crate::surface::SurfaceFit,
) -> bool {
    let Some(c) = covariance else {
        return false;
    };
    let e = fit.epoch;
    let at = |r: usize, q: usize| c.get((6 * e + r, 6 * e + q)).copied();
    let (Some(xx), Some(xy), Some(yy), Some(zz)) = (at(0, 0), at(0, 1), at(1, 1), at(5, 5)) else {
        return false;
    };
    let tilt_var = 0.5 * (xx + yy) + (0.25 * (xx - yy).powi(2) + xy * xy).sqrt();
    let (tilt_sigma, offset_sigma) = (tilt_var.max(0.0).sqrt(), zz.max(0.0).sqrt());
    let tilt = fit.plane[1].hypot(fit.plane[2]);
    let ok = fit.plane[0].abs() <= PLAUSIBLE_SIGMAS * offset_sigma
        && tilt <= PLAUSIBLE_SIGMAS * tilt_sigma;
    tracing::info!(
        epoch = name,
        offset = fit.plane[0],
        offset_sigma,
        tilt_mm_per_m = 1e3 * tilt,
        tilt_sigma_mm_per_m = 1e3 * tilt_sigma,
        held = ok,
        "an epoch's miss of the reference surface against what the block allows"
    );
    if !ok {
        tracing::warn!(
            "epoch {}: its tie points miss the reference epoch's surface by {:.3} m and {:.2} \
             mm/m, beyond {PLAUSIBLE_SIGMAS} σ of what the block allows ({:.3} m, {:.2} mm/m): \
             taken as change, not held to it (give stable.csv to say where the ground is stable)",
            name,
            fit.plane[0],
            1e3 * tilt,
            offset_sigma,
            1e3 * tilt_sigma
        );
    }
    ok
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::surface::SurfaceFit;

    /// A fit of epoch 1 with this offset (m) and tilt (m/m, eastwards).
    fn fit(offset: f64, tilt: f64) -> SurfaceFit {
        SurfaceFit {
            epoch: 1,
            compared: 100,
            kept: 100,
            sigma: 0.1,
            plane: [offset, tilt, 0.0],
            plane_std: [0.01, 1e-4, 1e-4],
            dome: None,
            height_scale: None,
            centroid: [0.0; 3],
            unchanged: Vec::new(),
            changed: Vec::new(),
        }
    }

    #[test]
    fn a_miss_within_ten_sigma_of_the_blocks_rigid_motion_is_held_and_beyond_is_change() {
        // Epoch 1's rotation σ 0.5 mm/m about x and 0.2 about y, vertical translation σ 0.1 m.
        let mut c = nalgebra::DMatrix::<f64>::zeros(12, 12);
        c[(6, 6)] = 0.5e-3f64.powi(2);
        c[(7, 7)] = 0.2e-3f64.powi(2);
        c[(11, 11)] = 0.01;
        assert!(plausible(Some(&c), "b", &fit(-0.24, 2.5e-3)));
        assert!(plausible(Some(&c), "b", &fit(0.99, 4.9e-3)));
        // A glacier's metres of thinning, or a tilt beyond 10 σ of the loosest axis.
        assert!(!plausible(Some(&c), "b", &fit(-4.0, 1e-3)));
        assert!(!plausible(Some(&c), "b", &fit(0.1, 5.1e-3)));
        // Without a covariance nothing can be judged: not held.
        assert!(!plausible(None, "b", &fit(0.0, 0.0)));
    }

    #[test]
    fn only_a_miss_beyond_three_of_its_own_sigma_and_half_a_ground_pixel_is_worth_holding() {
        // σ 0.01 m of offset, 0.1 mm/m of tilt; points up to 100 m from the centroid; a
        // ground pixel of 4 cm.
        let far = |mut f: SurfaceFit| {
            f.unchanged = vec![[100.0, 0.0], [0.0, 50.0]];
            f
        };
        assert!(significant(&far(fit(0.031, 0.0)), 0.04));
        assert!(significant(&far(fit(0.0, 0.31e-3)), 0.04));
        assert!(!significant(&far(fit(0.029, 0.29e-3)), 0.04));
        // Significant but smaller than half a ground pixel of 10 cm: 3.1 cm of offset, a
        // rise of 3.1 cm at 100 m.
        assert!(!significant(&far(fit(0.031, 0.31e-3)), 0.1));
    }
}
