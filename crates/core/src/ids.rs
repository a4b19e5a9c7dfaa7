//! Typed identifiers. Dense indices into the block's tables, never confused with one another.

use std::fmt;

macro_rules! id_type {
    ($(#[$doc:meta])* $name:ident, $prefix:literal) => {
        $(#[$doc])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
        pub struct $name(pub u32);

        impl $name {
            /// The id as an index into a table.
            pub fn index(self) -> usize {
                self.0 as usize
            }
        }

        impl From<usize> for $name {
            fn from(index: usize) -> Self {
                $name(u32::try_from(index).unwrap_or(u32::MAX))
            }
        }

        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                write!(f, concat!($prefix, "{}"), self.0)
            }
        }
    };
}

id_type!(
    /// An image of the project, all epochs together.
    ImageId, "image#"
);
id_type!(
    /// An epoch (one acquisition date / survey).
    EpochId, "epoch#"
);
id_type!(
    /// A camera group: images sharing one set of intrinsics.
    CameraGroupId, "camera#"
);
id_type!(
    /// A track: one 3-D tie point observed in several images.
    TrackId, "track#"
);
id_type!(
    /// The index of a keypoint within its image's feature list.
    FeatureIndex, "feature#"
);
