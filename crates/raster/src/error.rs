use thiserror::Error;

/// Why a lattice, a DEM or an orthomosaic could not be made.
#[derive(Debug, Error, PartialEq)]
pub enum RasterError {
    /// A lattice or grid option is out of its domain (cell size, extent, subdivision).
    #[error("invalid grid: {0}")]
    InvalidGrid(String),
    /// Nothing to grid: no point, or no point inside the lattice.
    #[error("no point of the cloud falls inside the grid ({0})")]
    NoPoints(String),
    /// A gridding or ortho option is out of its domain.
    #[error("invalid option: {0}")]
    InvalidOption(String),
    /// An input has the wrong size or non-finite values.
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// The caller could not take the rows of a mosaic (writing them failed).
    #[error("the mosaic's rows could not be written: {0}")]
    Output(String),
}
