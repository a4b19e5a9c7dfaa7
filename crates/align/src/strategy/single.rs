//! `timesift`: every epoch's images in one reconstruction and one georeferencing; with
//! [`SfmOptions::join_epoch_ties`], a second look for inter-epoch ties by descriptor (module
//! `joined`).

use crate::AlignError;
use crate::georef::Georeferenced;
use crate::incremental::reconstruct;
use crate::options::SfmOptions;

use super::block::Block;
use super::joined::second_look;
use super::method::{DatumControl, Method, Strategy};
use super::one_block::adjust_as_one_block;
use super::stp::StableMatcher;

/// `timesift`: one block.
#[derive(Default, Clone, Copy)]
pub struct SingleBlock<'m> {
    /// Descriptor matching of tie points, for the second look
    /// ([`SfmOptions::join_epoch_ties`]); without one, that option is an error.
    pub matcher: Option<&'m dyn StableMatcher>,
}

impl Strategy for SingleBlock<'_> {
    fn method(&self) -> Method {
        Method::Timesift
    }

    fn datum_control(&self) -> DatumControl {
        DatumControl::WholeBlock
    }

    fn orient(&self, block: &Block, options: &SfmOptions) -> Result<Georeferenced, AlignError> {
        let components = reconstruct(&block.sfm, options)?;
        let first = adjust_as_one_block(block, components, options)?;
        if !options.join_epoch_ties || block.epoch_names.len() < 2 {
            return Ok(first);
        }
        let matcher = self.matcher.ok_or_else(|| {
            AlignError::InvalidInput(
                "join_epoch_ties needs a descriptor matcher (SingleBlock::matcher)".into(),
            )
        })?;
        second_look(block, first, matcher, options)
    }
}
