//! `timesift`: every epoch's images in one reconstruction and one georeferencing; with
//! [`SfmOptions::join_epoch_ties`] or [`SfmOptions::guided_epoch_ties`], a second look for
//! inter-epoch ties by descriptor (modules `joined` and `guided`).

use crate::AlignError;
use crate::georef::Georeferenced;
use crate::global::orient_images;
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
    /// ([`SfmOptions::join_epoch_ties`], [`SfmOptions::guided_epoch_ties`]); without one,
    /// those options are an error.
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
        let ground = &block.ground;
        let (components, mapper) = orient_images(
            &block.sfm,
            &ground.centre_priors,
            &ground.prior_offsets,
            options,
        )?;
        let mut first = adjust_as_one_block(block, components, options)?;
        first.diagnostics.mapper = mapper;
        let second_look_asked = options.join_epoch_ties || options.guided_epoch_ties;
        if !second_look_asked || block.epoch_names.len() < 2 {
            return Ok(first);
        }
        let matcher = self.matcher.ok_or_else(|| {
            AlignError::InvalidInput(
                "join_epoch_ties and guided_epoch_ties need a descriptor matcher \
                 (SingleBlock::matcher)"
                    .into(),
            )
        })?;
        second_look(block, first, matcher, options)
    }
}
