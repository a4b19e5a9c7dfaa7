//! The co-registration strategies of docs/design.md behind one trait. A [`Block`] is the whole
//! multi-epoch input: epochs are only a partition of the images (which epoch each image belongs
//! to, which one carries the datum); what a strategy does with that partition is the strategy.
//! [`Method`] names them (the one place their names are spelt), [`strategy`] makes one.
//!
//! - [`SingleBlock`] (`timesift`, module `single`): all epochs in one reconstruction and one
//!   georeferencing (module `one_block`); optionally a second look for inter-epoch ties by
//!   descriptor (module `joined`).
//! - [`Independent`] (`independent`): each epoch reconstructed and georeferenced with its own
//!   priors and markers.
//! - [`ChunkAlignment`] (`chunk`): each epoch reconstructed alone; the reference epoch
//!   georeferenced; every other epoch mapped onto it by one 7-parameter similarity from the
//!   tie points the two epochs share (module `similarity`).
//! - [`ProgressiveMerge`] (`msfm`): epochs alone, merged into one block most-connected first.
//! - [`StableTiePoints`] (`stp`): stable tie points as control points.
//! - [`ManualStablePoints`] (`manual`): natural points measured by hand in several epochs,
//!   intersected in the reference, as control points of the others.
//!
//! The strategies that orient epochs together (`timesift`, `msfm`) split the tie points whose
//! epochs disagree (module `moved` of the crate).
//!
//! Files of this folder import `method` and `block` and the helpers below them, never this
//! file: only [`strategy`] here names every strategy, so no file imports one that imports it.

mod block;
mod chunk;
mod guided;
mod independent;
mod joined;
mod manual;
mod method;
mod msfm;
mod one_block;
mod similarity;
mod single;
mod stp;
mod track_sets;

pub use block::{Block, NaturalPoint};
pub use chunk::ChunkAlignment;
pub use independent::Independent;
pub use manual::{MIN_REFERENCE_IMAGES, ManualStablePoints};
pub use method::{DatumControl, Method, Strategy};
pub use msfm::ProgressiveMerge;
pub use single::SingleBlock;
pub use stp::{
    GuidedMatch, GuidedQuery, OfferedTiePoint, StableMatch, StableMatcher, StableSearch,
    StableTiePoints,
};

/// The strategy `method` names. `stp`, and `timesift` with
/// [`crate::SfmOptions::join_epoch_ties`], compare descriptors, which `matcher` does.
pub fn strategy<'m>(method: Method, matcher: &'m dyn StableMatcher) -> Box<dyn Strategy + 'm> {
    match method {
        Method::Timesift => Box::new(SingleBlock {
            matcher: Some(matcher),
        }),
        Method::Independent => Box::new(Independent),
        Method::Chunk => Box::new(ChunkAlignment),
        Method::Msfm => Box::new(ProgressiveMerge),
        Method::Stp => Box::new(StableTiePoints { matcher }),
        Method::Manual => Box::new(ManualStablePoints),
    }
}
