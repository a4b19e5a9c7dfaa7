//! `independent`: every epoch reconstructed and georeferenced alone, with its own priors and
//! markers (the classical way, and the baseline the others are judged against).

use crate::AlignError;
use crate::georef::Georeferenced;
use crate::options::SfmOptions;

use super::block::Block;
use super::method::{DatumControl, Method, Strategy};

/// `independent`: every epoch alone.
pub struct Independent;

impl Strategy for Independent {
    fn method(&self) -> Method {
        Method::Independent
    }

    fn datum_control(&self) -> DatumControl {
        DatumControl::OwnEpoch
    }

    fn orient(&self, block: &Block, options: &SfmOptions) -> Result<Georeferenced, AlignError> {
        let parts = (0..block.epoch_names.len())
            .map(|e| block.orient_epoch(e, options))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(block.merge(parts))
    }
}
