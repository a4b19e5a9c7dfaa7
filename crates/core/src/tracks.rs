//! Observations and tracks: one 3-D point seen in several images.

use nalgebra::Vector2;

use crate::{FeatureIndex, ImageId};

/// One image measurement of a point, in pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    /// The image measured.
    pub image: ImageId,
    /// The measured pixel position.
    pub pixel: Vector2<f64>,
    /// Standard deviation of the measurement in pixels (tie-point or marker accuracy).
    pub sigma_px: f64,
}

/// A reference to one keypoint of one image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct TrackElement {
    /// The image.
    pub image: ImageId,
    /// The keypoint within that image.
    pub feature: FeatureIndex,
}

/// A track: the keypoints, at most one per image, that see the same 3-D point.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Track {
    /// The keypoints, sorted by image.
    pub elements: Vec<TrackElement>,
}

impl Track {
    /// A track from elements, sorted by image. Returns `None` when two elements share an image:
    /// such a track is inconsistent and must be split or dropped by whoever built it.
    pub fn new(mut elements: Vec<TrackElement>) -> Option<Track> {
        elements.sort();
        if elements.windows(2).any(|w| w[0].image == w[1].image) {
            return None;
        }
        Some(Track { elements })
    }

    /// Number of images observing the track.
    pub fn len(&self) -> usize {
        self.elements.len()
    }

    /// Whether the track has no element.
    pub fn is_empty(&self) -> bool {
        self.elements.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn track_rejects_two_features_of_one_image() {
        let e = |i, f| TrackElement {
            image: ImageId(i),
            feature: FeatureIndex(f),
        };
        assert!(Track::new(vec![e(2, 1), e(1, 5), e(2, 7)]).is_none());
        let t = Track::new(vec![e(3, 1), e(1, 5)]).unwrap();
        assert_eq!(t.elements[0].image, ImageId(1));
        assert_eq!(t.len(), 2);
    }
}
