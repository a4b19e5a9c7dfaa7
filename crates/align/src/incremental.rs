//! Incremental structure from motion: initial pair, then one image at a time (absolute pose,
//! triangulation of the tracks it completes, local adjustment around it, filtering), with a global
//! adjustment and re-triangulation whenever the block has grown by a set factor, and a final
//! adjustment with the full self-calibration. Images left over start new components.

use std::collections::HashMap;

use crate::AlignError;
use crate::adjust::{Adjustment, CentrePrior, Intrinsics, OffsetPrior, TIE_POINT_LOSS};
use crate::init::initialise;
use crate::model::{Reconstruction, SfmInput};
use crate::options::SfmOptions;
use crate::register::{candidates, estimate_pose};
use crate::state::{State, track_table};

/// Orients the images of `input`: every connected component of at least
/// `options.min_component_images` images, largest first. Components share no image; each has
/// its own arbitrary similarity frame (georeferencing puts them in one). Fails when not even one
/// initial pair can be found.
pub fn reconstruct(
    input: &SfmInput,
    options: &SfmOptions,
) -> Result<Vec<Reconstruction>, AlignError> {
    input.validate()?;
    options.validate()?;
    let track_of = track_table(input);
    let mut available = vec![true; input.images.len()];
    let mut components: Vec<Reconstruction> = Vec::new();
    loop {
        let mut state = State::new(input, options, &track_of, available.clone());
        match initialise(&mut state) {
            Ok(_) => {}
            Err(e) if components.is_empty() => return Err(e),
            Err(_) => break,
        }
        grow(&mut state)?;
        finish(&mut state)?;
        let oriented = state.oriented();
        for &i in &oriented {
            available[i] = false;
        }
        tracing::info!(
            component = components.len(),
            images = oriented.len(),
            points = state.rec.points.len(),
            "component oriented"
        );
        if oriented.len() >= options.min_component_images {
            components.push(state.rec);
        }
        if available.iter().filter(|a| **a).count() < options.min_component_images.max(2) {
            break;
        }
    }
    components.sort_by_key(|c| std::cmp::Reverse(c.num_oriented()));
    Ok(components)
}

/// Registers images until none can be.
pub(crate) fn grow(state: &mut State<'_>) -> Result<(), AlignError> {
    global(state, Intrinsics::Fixed)?;
    let mut last_global = state.oriented().len();
    let mut retried = false;
    loop {
        let mut registered = None;
        for image in candidates(state) {
            match estimate_pose(state, image) {
                Some((pose, inliers)) => {
                    state.rec.poses[image] = Some(pose);
                    tracing::debug!(image, inliers, "image oriented");
                    registered = Some(image);
                    break;
                }
                None => state.failed_trials[image] += 1,
            }
        }
        let Some(image) = registered else {
            // A global adjustment and re-triangulation may give the failed images more points.
            if retried || state.failed_trials.iter().all(|&n| n == 0) {
                break;
            }
            retried = true;
            global(state, Intrinsics::Running)?;
            state.failed_trials.fill(0);
            continue;
        };
        retried = false;
        state.complete_tracks_of_image(image);
        local(state, image)?;
        let n = state.oriented().len();
        if n as f64 >= last_global as f64 * state.options.global_adjustment_growth {
            global(state, Intrinsics::Running)?;
            state.failed_trials.fill(0);
            last_global = n;
        }
    }
    Ok(())
}

/// Adjusts a new image with the oriented images sharing the most points with it, then filters
/// their points and completes the new image's tracks.
fn local(state: &mut State<'_>, image: usize) -> Result<(), AlignError> {
    let mut shared: HashMap<usize, usize> = HashMap::new();
    for p in state.points_seen_by(&[image]) {
        for e in &state.rec.points[p].observations {
            if e.image.index() != image {
                *shared.entry(e.image.index()).or_insert(0) += 1;
            }
        }
    }
    let mut neighbours: Vec<(usize, usize)> = shared.into_iter().collect();
    neighbours.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    let mut free = vec![image];
    free.extend(
        neighbours
            .iter()
            .take(state.options.local_adjustment_images.saturating_sub(1))
            .map(|n| n.0),
    );
    let points = state.points_seen_by(&free);
    if points.is_empty() {
        return Ok(());
    }
    state.adjust(&Adjustment {
        free_images: free,
        points: points.clone(),
        intrinsics: Intrinsics::Fixed,
        priors: &[],
        offsets: &[],
        marked: &[],
        loss: TIE_POINT_LOSS,
        iterations: state.options.local_iterations,
        focal_fixed: &[],
        precision: false,
        rigid_sets: &[],
        heights: &[],
    })?;
    state.filter_points(&points);
    state.complete_tracks_of_image(image);
    Ok(())
}

/// Adjusts every oriented image and point, filters, re-triangulates and compacts.
pub(crate) fn global(state: &mut State<'_>, intrinsics: Intrinsics) -> Result<(), AlignError> {
    let points = state.live_points();
    let iterations = state.options.global_iterations;
    let report = adjust_oriented_images(state, points.clone(), intrinsics, iterations, &[], &[])?;
    let dropped = state.filter_points(&points);
    let added = state.complete_all_tracks();
    state.compact();
    tracing::debug!(
        images = state.oriented().len(),
        points = state.rec.points.len(),
        rms_px = report.rms_px,
        iterations = report.iterations,
        linear_iterations = report.linear_iterations,
        initial_cost = report.initial_cost,
        termination = ?report.termination,
        dropped,
        added,
        "global adjustment"
    );
    Ok(())
}

/// Adjusts every oriented image with `points` by their tie points and `priors` (with the
/// flights' `offsets` they refer to); no marker or height. Without priors the frame stays the
/// block's own.
pub(crate) fn adjust_oriented_images(
    state: &mut State<'_>,
    points: Vec<usize>,
    intrinsics: Intrinsics,
    iterations: usize,
    priors: &[CentrePrior],
    offsets: &[OffsetPrior],
) -> Result<timesift_bundle::BundleReport, AlignError> {
    let focal_fixed = state.input.focal_held_during_sfm();
    Ok(state
        .adjust(&Adjustment {
            free_images: state.oriented(),
            points,
            intrinsics,
            priors,
            offsets,
            marked: &[],
            loss: TIE_POINT_LOSS,
            iterations,
            // A focal length from EXIF stays until georeferencing can tell whether the block
            // determines it (a nadir block over flat ground does not: f trades with height).
            focal_fixed: &focal_fixed,
            precision: false,
            rigid_sets: &[],
            heights: &[],
        })?
        .report)
}

/// The final adjustments with the full self-calibration.
pub(crate) fn finish(state: &mut State<'_>) -> Result<(), AlignError> {
    global(state, Intrinsics::Final)?;
    global(state, Intrinsics::Final)?;
    Ok(())
}
