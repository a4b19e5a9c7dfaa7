//! The closed set of co-registration strategies ([`Method`]), the one place their names are
//! spelt, and the trait every strategy implements.

use crate::AlignError;
use crate::georef::Georeferenced;
use crate::options::SfmOptions;

use super::block::Block;

/// A co-registration strategy of docs/design.md, by name (`align.method` of a project).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Method {
    /// One bundle block for all epochs (the default).
    #[default]
    Timesift,
    /// Each epoch oriented and georeferenced alone.
    Independent,
    /// Epochs oriented alone, then aligned to the reference by one similarity (Helmert).
    Chunk,
    /// Epochs oriented alone, then merged progressively into one block.
    Msfm,
    /// Stable tie points of the reference epoch as control for the others.
    Stp,
    /// Natural stable points measured by hand, intersected in the reference epoch, as control
    /// points of the others (Garieri's Method 1).
    Manual,
}

impl Method {
    /// Every strategy, in the order of the papers that compare them (Garieri et al. 2021),
    /// which benches and messages follow.
    pub const ALL: [Method; 6] = [
        Method::Timesift,
        Method::Independent,
        Method::Chunk,
        Method::Stp,
        Method::Msfm,
        Method::Manual,
    ];

    /// Its name in `project.toml`, reports and benches.
    pub fn name(self) -> &'static str {
        match self {
            Method::Timesift => "timesift",
            Method::Independent => "independent",
            Method::Chunk => "chunk",
            Method::Msfm => "msfm",
            Method::Stp => "stp",
            Method::Manual => "manual",
        }
    }

    /// Every name, in the order of [`Method::ALL`], joined by `separator` (for messages and
    /// comments).
    pub fn names(separator: &str) -> String {
        Method::ALL.map(Method::name).join(separator)
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Method {
    type Err = AlignError;

    fn from_str(name: &str) -> Result<Method, AlignError> {
        Method::ALL
            .into_iter()
            .find(|m| m.name() == name)
            .ok_or_else(|| {
                AlignError::InvalidInput(format!(
                    "unknown method `{name}`, expected one of {}",
                    Method::names(", ")
                ))
            })
    }
}

#[cfg(feature = "serde")]
impl serde::Serialize for Method {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.name())
    }
}

#[cfg(feature = "serde")]
impl<'de> serde::Deserialize<'de> for Method {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Method, D::Error> {
        let name = <std::borrow::Cow<'de, str>>::deserialize(deserializer)?;
        name.parse().map_err(|_| {
            serde::de::Error::custom(format!(
                "unknown variant `{name}`, expected one of {}",
                Method::names(", ")
            ))
        })
    }
}

/// Whose control fixes an epoch's datum under a strategy: what the tilt a datum's control
/// allows ([`crate::datum_tilt`]) must be computed from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DatumControl {
    /// One adjustment of every epoch: the control of all epochs fixes each (`timesift`,
    /// `msfm`).
    WholeBlock,
    /// Each epoch by its own control alone (`independent`).
    OwnEpoch,
    /// The reference epoch by its own control; the others through the reference epoch, by
    /// ties the control does not describe (`chunk`, `stp`, `manual`).
    ThroughReference,
}

/// A co-registration strategy.
pub trait Strategy {
    /// Which one it is.
    fn method(&self) -> Method;
    /// Whose control fixes each epoch's datum.
    fn datum_control(&self) -> DatumControl;
    /// Orients and georeferences every epoch.
    fn orient(&self, block: &Block, options: &SfmOptions) -> Result<Georeferenced, AlignError>;
}
