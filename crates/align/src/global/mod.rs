//! Global structure from motion seeded by GNSS: every pair's relative rotation and direction
//! (module `two_view`), the images' rotations averaged over all pairs at once (`rotations`),
//! turned into the priors' frame by the baselines and the centres solved against the pairs'
//! directions and the priors with an offset per flight (`positions`), then the tracks
//! triangulated under a loose bound and the block adjusted, filtered and completed as the
//! incremental mapper finishes its blocks (images left out are registered by resection).
//!
//! Why: the incremental mapper adjusts the whole block each time it grew by a tenth, which is
//! tens of adjustments of a growing block; here the block is adjusted a handful of times, and the
//! linear algebra before it (graph-shaped systems solved by conjugate gradients, `solve`) costs
//! seconds at thousands of images. The priors are needed: without them the positions would need
//! a translation averaging of their own, and [`Mapper::Global`] falls back to the incremental
//! mapper, as it does when the pairs cannot place the rotations in the priors' frame.

mod positions;
mod rotations;
mod solve;
mod two_view;

use timesift_core::Pose;

use crate::AlignError;
use crate::adjust::{CentrePrior, Intrinsics, OffsetPrior};
use crate::incremental::{adjust_oriented_images, finish, grow, reconstruct};
use crate::model::{Reconstruction, SfmInput};
use crate::options::{GLOBAL_MAPPER_FROM_IMAGES, Mapper, SfmOptions};
use crate::state::{State, track_table};

/// The first adjustment of the seeded block keeps observations within this many times
/// [`SfmOptions::max_reprojection_px`]: the priors' noise within a flight (decimetres) puts
/// the seeded cameras some pixels off, and what the adjustment cannot pull in is dropped after.
const SEED_BOUND_FACTOR: f64 = 4.0;

/// Points per image in the first adjustment of the seeded block ([`adjust_on_a_subset`]).
const SUBSET_POINTS_PER_IMAGE: usize = 160;
/// The subset's points are chosen per cell of this many × this many in each image, so that
/// they cover the whole frame (the distortion is found at its edges).
const SUBSET_GRID: usize = 4;

/// The first adjustment of the seeded block, on each image's [`SUBSET_POINTS_PER_IMAGE`]
/// longest tracks only (spread over its frame), with the intrinsics the growing blocks of the
/// incremental mapper estimate ([`Intrinsics::Running`]) and the centre priors that seeded it
/// (their flights' offsets starting where [`positions::solve_centres`] put them). Returns the
/// subset and the adjustment's RMS, pixels.
/// Why: from the seed the adjustment has the whole block's camera errors and the intrinsics to
/// find at once (the incremental mapper finds them as the block grows), which takes tens of
/// iterations; on a tenth of the points each costs a tenth, and the adjustments of the whole
/// block after it start converged. Why the priors: without them the block's scale and
/// position are free, a direction the damped solver walks along slowly (scale-400: 64
/// iterations without them, 30 with them, to the same RMS).
fn adjust_on_a_subset(
    state: &mut State<'_>,
    priors: &[CentrePrior],
    offsets: &[OffsetPrior],
) -> Result<(Vec<usize>, f64), AlignError> {
    // Per image and cell of a SUBSET_GRID × SUBSET_GRID grid: (observations, point).
    let cells = SUBSET_GRID * SUBSET_GRID;
    let cell_of = |v: f64, size: u32| {
        ((v / size as f64 * SUBSET_GRID as f64).max(0.0) as usize).min(SUBSET_GRID - 1)
    };
    let mut by_cell: Vec<Vec<(usize, usize)>> = vec![Vec::new(); state.input.images.len() * cells];
    for (p, point) in state.rec.points.iter().enumerate() {
        for e in &point.observations {
            let image = e.image.index();
            let camera = state.rec.camera_of(state.input, image);
            let pixel = state.input.pixel(e);
            let cell =
                cell_of(pixel.y, camera.height()) * SUBSET_GRID + cell_of(pixel.x, camera.width());
            by_cell[image * cells + cell].push((point.observations.len(), p));
        }
    }
    let per_cell = SUBSET_POINTS_PER_IMAGE.div_ceil(cells);
    let mut subset: Vec<usize> = Vec::new();
    for points in &mut by_cell {
        points.sort_by(|x, y| y.0.cmp(&x.0).then(x.1.cmp(&y.1)));
        subset.extend(points.iter().take(per_cell).map(|x| x.1));
    }
    subset.sort_unstable();
    subset.dedup();
    let iterations = 4 * state.options.global_iterations;
    let report = adjust_oriented_images(
        state,
        subset.clone(),
        Intrinsics::Running,
        iterations,
        priors,
        offsets,
    )?;
    tracing::debug!(
        points = subset.len(),
        rms_px = report.rms_px,
        iterations = report.iterations,
        linear_iterations = report.linear_iterations,
        "global mapper: seeded block adjusted on a subset of its points"
    );
    Ok((subset, report.rms_px))
}

/// Every point outside `subset` was triangulated from the seeded cameras: it is triangulated
/// again from the adjusted ones (under the current bound), and the subset filtered by it.
fn triangulate_again_outside(state: &mut State<'_>, subset: &[usize]) {
    let mut keep = vec![false; state.rec.points.len()];
    for &p in subset {
        keep[p] = true;
    }
    for (p, keep) in keep.into_iter().enumerate() {
        if !keep {
            state.kill_point(p);
        }
    }
    state.filter_points(subset);
    state.compact();
    state.complete_all_tracks();
}

/// An image whose seeded pose sees under this share of the median image's observations once
/// the tracks are triangulated is seeded wrong (a relative rotation the averaging could not
/// outvote, a direction along a degenerate baseline): its pose is dropped and the incremental
/// mapper's resection orients it after the first adjustment.
const MIN_SEEN_SHARE: f64 = 0.25;

/// Drops the poses of the images seen by fewer than [`MIN_SEEN_SHARE`] of the median image's
/// observations (and fewer than [`SfmOptions::abs_pose_min_inliers`]), with their
/// observations. Returns how many.
fn drop_poorly_seen_images(state: &mut State<'_>) -> usize {
    let mut seen = vec![0usize; state.input.images.len()];
    for point in &state.rec.points {
        for e in &point.observations {
            seen[e.image.index()] += 1;
        }
    }
    let oriented = state.oriented();
    let mut counts: Vec<usize> = oriented.iter().map(|&i| seen[i]).collect();
    if counts.is_empty() {
        return 0;
    }
    let mid = counts.len() / 2;
    let median = *counts.select_nth_unstable(mid).1;
    let bound = (MIN_SEEN_SHARE * median as f64).max(state.options.abs_pose_min_inliers as f64);
    let dropped: Vec<usize> = oriented
        .into_iter()
        .filter(|&i| (seen[i] as f64) < bound && i != state.gauge)
        .collect();
    for &i in &dropped {
        state.rec.poses[i] = None;
    }
    if !dropped.is_empty() {
        // The dropped images have no pose now: their observations go.
        let poses = &state.rec.poses;
        for point in &mut state.rec.points {
            point
                .observations
                .retain(|e| poses[e.image.index()].is_some());
        }
        let all = state.live_points();
        state.filter_points(&all);
        state.compact();
        tracing::debug!(
            ?dropped,
            "global mapper: poorly seen seeded images left to resection"
        );
    }
    dropped.len()
}

/// The images of `input` oriented by the mapper `options` choose: the components of the
/// incremental mapper (largest first, arbitrary frames), or the one block of the global mapper
/// near the priors' frame; and the mapper that did it (never [`Mapper::Auto`]).
pub(crate) fn orient_images(
    input: &SfmInput,
    priors: &[CentrePrior],
    offsets: &[OffsetPrior],
    options: &SfmOptions,
) -> Result<(Vec<Reconstruction>, Mapper), AlignError> {
    let global = match options.mapper {
        Mapper::Global => true,
        Mapper::Auto => input.images.len() >= GLOBAL_MAPPER_FROM_IMAGES,
        Mapper::Incremental => false,
    };
    if global {
        if let Some(block) = reconstruct_global(input, priors, offsets, options)? {
            return Ok((vec![block], Mapper::Global));
        }
        tracing::warn!(
            "the global mapper needs GNSS priors, pairs within one flight in more than one \
             direction to turn the rotations onto them, and a seeded block that converges; \
             orienting incrementally instead"
        );
    }
    Ok((reconstruct(input, options)?, Mapper::Incremental))
}

/// The global mapper (module docs); `None` when the priors or the pairs do not suffice. The
/// block comes out near the priors' frame (its adjustments have no priors, one image holding
/// the datum: georeferencing places it).
fn reconstruct_global(
    input: &SfmInput,
    priors: &[CentrePrior],
    offsets: &[OffsetPrior],
    options: &SfmOptions,
) -> Result<Option<Reconstruction>, AlignError> {
    input.validate()?;
    options.validate()?;
    let images = input.images.len();
    let mut flight_of = vec![None; images];
    for prior in priors {
        if let Some(slot) = flight_of.get_mut(prior.image) {
            *slot = prior.offset;
        }
    }
    let views = two_view::relative_poses(input, options, &flight_of);
    let averaged = rotations::average_rotations(images, &views);
    let directed = positions::directed_views(&views, &averaged);
    let Some(frame) = positions::frame_rotation(&directed, priors, images) else {
        return Ok(None);
    };
    // R' = R Qᵀ: cam from priors' frame = cam from averaging frame ∘ averaging from priors'.
    let inverse = frame.inverse();
    let averaged: Vec<_> = averaged.iter().map(|r| r.map(|r| r * inverse)).collect();
    let directed: Vec<_> = directed.into_iter().map(|(v, d)| (v, frame * d)).collect();
    let Some(placed) = positions::solve_centres(images, &directed, priors, offsets) else {
        return Ok(None);
    };
    let track_of = track_table(input);
    let mut state = State::new(input, options, &track_of, vec![true; images]);
    for (i, (rotation, centre)) in averaged.iter().zip(&placed.centres).enumerate() {
        if let (Some(rotation), Some(centre)) = (rotation, centre) {
            state.rec.poses[i] = Some(Pose::from_rotation_and_center(*rotation, centre));
        }
    }
    let seeded = state.oriented();
    tracing::info!(
        pairs = views.len(),
        directed = directed.len(),
        seeded = seeded.len(),
        flights = ?placed.offsets,
        "global mapper: rotations averaged and centres placed"
    );
    if seeded.len() < options.min_component_images.max(2) {
        return Ok(None);
    }
    state.gauge = seeded[0];
    state.max_error_px = SEED_BOUND_FACTOR * options.max_reprojection_px;
    state.complete_all_tracks();
    let unseeded = drop_poorly_seen_images(&mut state);
    state.offsets = placed.offsets;
    let (subset, rms_px) = adjust_on_a_subset(&mut state, priors, offsets)?;
    // A wrong seed (a frame turned the wrong way, centres metres off) leaves few points, or
    // points that no adjustment brings within the bound: the incremental mapper then.
    if !(rms_px <= options.max_reprojection_px) || subset.len() < seeded.len() {
        tracing::warn!(
            rms_px,
            points = subset.len(),
            "global mapper: the seeded block did not converge"
        );
        return Ok(None);
    }
    state.max_error_px = options.max_reprojection_px;
    triangulate_again_outside(&mut state, &subset);
    if state.oriented().len() < images {
        grow(&mut state)?;
    }
    finish(&mut state)?;
    tracing::info!(
        images = state.oriented().len(),
        unseeded,
        points = state.rec.points.len(),
        "global mapper: block oriented"
    );
    Ok(Some(state.rec))
}
