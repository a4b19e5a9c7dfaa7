//! `msfm` (multi-temporal SfM): epochs reconstructed alone (initial values and per-camera
//! calibration), merged into one block most-connected first, each merge adjusted, then the
//! whole block adjusted and georeferenced as `timesift`'s is.

use crate::AlignError;
use crate::adjust::Intrinsics;
use crate::georef::Georeferenced;
use crate::incremental::{global, reconstruct};
use crate::model::Reconstruction;
use crate::options::SfmOptions;
use crate::state::{State, track_table};

use super::block::{Block, adopt_oriented};
use super::method::{DatumControl, Method, Strategy};
use super::one_block::adjust_as_one_block;
use super::similarity::{fit_similarity, placed_or_left_out, point_index, shared_points};

/// `msfm`: epochs alone, merged progressively, adjusted and georeferenced together.
pub struct ProgressiveMerge;

/// A component of one epoch's own reconstruction, waiting to be merged.
struct EpochPart {
    epoch: usize,
    /// The largest component of its epoch (which must be placed).
    largest: bool,
    rec: Reconstruction,
}

impl Strategy for ProgressiveMerge {
    fn method(&self) -> Method {
        Method::Msfm
    }

    fn datum_control(&self) -> DatumControl {
        DatumControl::WholeBlock
    }

    fn orient(&self, block: &Block, options: &SfmOptions) -> Result<Georeferenced, AlignError> {
        let track_of = track_table(&block.sfm);
        let mut parts = epoch_parts(block, &track_of, options)?;
        let at = parts
            .iter()
            .position(|p| p.epoch == block.reference && p.largest)
            .unwrap_or(0);
        let mut merged = parts.swap_remove(at).rec;
        let mut dropped_parts = 0;
        while !parts.is_empty() {
            let placed;
            (merged, placed) = merge_most_connected(block, merged, &mut parts, &track_of, options)?;
            if !placed {
                dropped_parts += 1;
            }
        }
        let mut placed = adjust_as_one_block(block, vec![merged], options)?;
        placed.diagnostics.dropped_components += dropped_parts;
        Ok(placed)
    }
}

/// Every component of every epoch, reconstructed alone, its points renumbered to the whole
/// block's tracks.
fn epoch_parts(
    block: &Block,
    track_of: &[Vec<u32>],
    options: &SfmOptions,
) -> Result<Vec<EpochPart>, AlignError> {
    let mut parts = Vec::new();
    for e in 0..block.epoch_names.len() {
        let sub = block.epoch_input(e);
        let components = reconstruct(&sub, options).map_err(|source| block.in_epoch(e, source))?;
        if components.is_empty() {
            return Err(block.in_epoch(e, AlignError::Georeferencing("empty".into())));
        }
        for (k, mut rec) in components.into_iter().enumerate() {
            // Points name tracks of the epoch's own input; renumber them to the whole block's.
            for p in &mut rec.points {
                if let Some(o) = p.observations.first() {
                    p.track = track_of[o.image.index()][o.feature.index()] as usize;
                }
            }
            parts.push(EpochPart {
                epoch: e,
                largest: k == 0,
                rec,
            });
        }
    }
    Ok(parts)
}

/// Takes the part sharing the most tie points with the block so far out of `parts`, places it
/// by a similarity and adjusts the block with it; the block, and false when the part could not
/// be placed (and is left out).
fn merge_most_connected(
    block: &Block,
    merged: Reconstruction,
    parts: &mut Vec<EpochPart>,
    track_of: &[Vec<u32>],
    options: &SfmOptions,
) -> Result<(Reconstruction, bool), AlignError> {
    let input = &block.sfm;
    let index = point_index(&merged);
    let (k, (src, dst)) = parts
        .iter()
        .map(|p| shared_points(&input.tracks, &p.rec, &merged, &index))
        .enumerate()
        .max_by_key(|(_, (src, _))| src.len())
        .ok_or_else(|| AlignError::Georeferencing("no epoch left".into()))?;
    let EpochPart {
        epoch,
        largest,
        mut rec,
    } = parts.swap_remove(k);
    let fit = fit_similarity(&src, &dst, &merged, options.seed);
    let Some(block_from_epoch) = placed_or_left_out(block, epoch, largest, &rec, fit)? else {
        return Ok((merged, false));
    };
    rec.transform(&block_from_epoch);
    let mut merged = merged;
    adopt_oriented(&mut merged, &rec, input);
    let mut state = State::with_reconstruction(input, options, track_of, merged);
    state.complete_all_tracks();
    global(&mut state, Intrinsics::Running)?;
    tracing::debug!(epoch, points = state.rec.points.len(), "epoch merged");
    Ok((state.rec, true))
}
