//! `chunk` (Metashape's "align chunks"): each epoch reconstructed alone; the reference epoch
//! georeferenced; every other epoch mapped onto it by one 7-parameter similarity from the tie
//! points the two epochs share (tracks spanning both), RANSAC then least squares.

use crate::AlignError;
use crate::georef::Georeferenced;
use crate::incremental::reconstruct;
use crate::options::SfmOptions;

use super::block::Block;
use super::method::{DatumControl, Method, Strategy};
use super::similarity::{fit_similarity, placed_or_left_out, point_index, shared_points};

/// `chunk`: epochs alone, then a similarity onto the reference epoch.
pub struct ChunkAlignment;

impl Strategy for ChunkAlignment {
    fn method(&self) -> Method {
        Method::Chunk
    }

    fn datum_control(&self) -> DatumControl {
        DatumControl::ThroughReference
    }

    fn orient(&self, block: &Block, options: &SfmOptions) -> Result<Georeferenced, AlignError> {
        let r = block.reference;
        let reference = block.orient_epoch(r, options)?;
        let reference_points = point_index(&reference.reconstruction);
        let mut parts = vec![reference.clone()];
        let mut dropped_parts = 0;
        for e in (0..block.epoch_names.len()).filter(|&e| e != r) {
            let sub = block.epoch_input(e);
            let components =
                reconstruct(&sub, options).map_err(|source| block.in_epoch(e, source))?;
            if components.is_empty() {
                return Err(block.in_epoch(e, AlignError::Georeferencing("empty".into())));
            }
            // Every component of the epoch goes onto the reference by the tie points it shares
            // with it; the largest must, the others are dropped (and counted) when they cannot.
            for (k, mut rec) in components.into_iter().enumerate() {
                let (src, dst) = shared_points(
                    &block.sfm.tracks,
                    &rec,
                    &reference.reconstruction,
                    &reference_points,
                );
                let fit = fit_similarity(&src, &dst, &reference.reconstruction, options.seed);
                let Some(ref_from_epoch) = placed_or_left_out(block, e, k == 0, &rec, fit)? else {
                    dropped_parts += 1;
                    continue;
                };
                rec.transform(&ref_from_epoch);
                parts.push(Georeferenced::unadjusted(&sub, rec, reference.datum));
            }
        }
        let mut merged = block.merge(parts);
        merged.diagnostics.dropped_components += dropped_parts;
        Ok(merged)
    }
}
