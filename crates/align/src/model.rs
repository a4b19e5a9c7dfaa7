//! What orientation consumes and produces: images as keypoint positions in camera groups,
//! tracks over them, and the reconstruction (cameras, poses, sparse points).

use nalgebra::{Vector2, Vector3};
use timesift_core::{Camera, CameraModel, Pose, Track, TrackElement, project_world};
use timesift_geometry::similarity::Similarity;

use crate::AlignError;

/// One image to orient: its camera group and the pixel position of each of its keypoints
/// (docs/design.md pixel convention), indexed by `FeatureIndex`.
#[derive(Debug, Clone, PartialEq)]
pub struct SfmImage {
    /// Index into [`SfmInput::cameras`].
    pub group: usize,
    /// Keypoint positions, pixels.
    pub keypoints: Vec<Vector2<f64>>,
}

/// The input of structure from motion: initial cameras per group, images, and tracks (each at
/// most one keypoint per image, as `timesift-matching` builds them).
#[derive(Debug, Clone, PartialEq)]
pub struct SfmInput {
    /// Initial intrinsics per camera group (EXIF focal length or a default).
    pub cameras: Vec<Camera>,
    /// The images.
    pub images: Vec<SfmImage>,
    /// Tracks over the images' keypoints.
    pub tracks: Vec<Track>,
    /// Per camera group: where the initial focal length comes from. Empty: all guessed.
    pub focal: Vec<FocalSource>,
}

/// What is known of a camera group's focal length before orientation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FocalSource {
    /// A default (1.2 × the long side): self-calibration decides.
    #[default]
    Guessed,
    /// A nominal value (EXIF, ±2 %): held during structure from motion, and at georeferencing
    /// where the block does not determine it (a nadir block over flat ground trades f with height).
    Nominal,
    /// A calibrated value (a camera calibration certificate): held throughout.
    Calibrated,
}

impl FocalSource {
    /// Whether structure from motion keeps the initial focal length.
    pub fn held_during_sfm(self) -> bool {
        self != FocalSource::Guessed
    }
}

impl SfmInput {
    /// Where camera group `g`'s focal length comes from.
    pub fn focal_source(&self, g: usize) -> FocalSource {
        self.focal.get(g).copied().unwrap_or_default()
    }

    /// Per camera group: whether structure from motion holds the focal length.
    pub(crate) fn focal_held_during_sfm(&self) -> Vec<bool> {
        (0..self.cameras.len())
            .map(|g| self.focal_source(g).held_during_sfm())
            .collect()
    }

    /// Checks that every group, image and keypoint referred to exists and that pixels are finite.
    pub fn validate(&self) -> Result<(), AlignError> {
        if !self.focal.is_empty() && self.focal.len() != self.cameras.len() {
            return Err(AlignError::InvalidInput(format!(
                "focal has {} entries for {} camera groups",
                self.focal.len(),
                self.cameras.len()
            )));
        }
        for (i, image) in self.images.iter().enumerate() {
            if image.group >= self.cameras.len() {
                return Err(AlignError::InvalidInput(format!(
                    "image {i} refers to camera group {} of {}",
                    image.group,
                    self.cameras.len()
                )));
            }
            if !image
                .keypoints
                .iter()
                .all(|p| p.x.is_finite() && p.y.is_finite())
            {
                return Err(AlignError::InvalidInput(format!(
                    "image {i} has a non-finite keypoint position"
                )));
            }
        }
        for (t, track) in self.tracks.iter().enumerate() {
            if track.elements.windows(2).any(|w| w[0].image >= w[1].image) {
                return Err(AlignError::InvalidInput(format!(
                    "track {t} is not sorted by image or has two keypoints in one image"
                )));
            }
            for e in &track.elements {
                let ok = self
                    .images
                    .get(e.image.index())
                    .is_some_and(|im| e.feature.index() < im.keypoints.len());
                if !ok {
                    return Err(AlignError::InvalidInput(format!(
                        "track {t} refers to keypoint {} of image {}, which does not exist",
                        e.feature.index(),
                        e.image.index()
                    )));
                }
            }
        }
        Ok(())
    }

    /// The pixel of a track element.
    pub fn pixel(&self, e: &TrackElement) -> Vector2<f64> {
        self.images[e.image.index()].keypoints[e.feature.index()]
    }
}

/// A triangulated tie point.
#[derive(Debug, Clone, PartialEq)]
pub struct SparsePoint {
    /// World position.
    pub position: Vector3<f64>,
    /// Index of its track in [`SfmInput::tracks`].
    pub track: usize,
    /// The track elements that measure it (in oriented images, within the reprojection
    /// threshold), sorted by image.
    pub observations: Vec<TrackElement>,
}

/// An oriented block, or one connected component of it.
#[derive(Debug, Clone, PartialEq)]
pub struct Reconstruction {
    /// Intrinsics per camera group (adjusted where self-calibration ran).
    pub cameras: Vec<Camera>,
    /// `cam_from_world` per image, `None` when not oriented.
    pub poses: Vec<Option<Pose>>,
    /// Tie points.
    pub points: Vec<SparsePoint>,
}

impl Reconstruction {
    /// Number of oriented images.
    pub fn num_oriented(&self) -> usize {
        self.poses.iter().flatten().count()
    }

    /// Reprojection error of every observation, pixels, in point order (infinite when a point
    /// does not project).
    pub fn residuals<'a>(
        &'a self,
        input: &'a SfmInput,
    ) -> impl Iterator<Item = (TrackElement, f64)> + 'a {
        self.points.iter().flat_map(move |p| {
            p.observations.iter().map(move |e| {
                let image = e.image.index();
                let error = match self.poses[image] {
                    Some(pose) => {
                        let camera = &self.cameras[input.images[image].group];
                        project_world(camera, &pose, &p.position)
                            .map_or(f64::INFINITY, |u| (u - input.pixel(e)).norm())
                    }
                    None => f64::INFINITY,
                };
                (*e, error)
            })
        })
    }

    /// Root mean square reprojection error over all observations, pixels (NaN without any).
    pub fn rms_px(&self, input: &SfmInput) -> f64 {
        let (sum, n) = self
            .residuals(input)
            .fold((0.0, 0usize), |(s, n), (_, e)| (s + e * e, n + 1));
        (sum / n as f64).sqrt()
    }

    /// Maps the block into another frame, `new_from_old`: points move, cameras follow
    /// (`R' = R sRᵀ`, `t' = s t − R' T`, so every projection is unchanged).
    pub fn transform(&mut self, new_from_old: &Similarity) {
        for point in &mut self.points {
            point.position = new_from_old.apply(&point.position);
        }
        let r_inv = new_from_old.rotation.inverse();
        for pose in self.poses.iter_mut().flatten() {
            let rotation = pose.rotation * r_inv;
            let translation =
                pose.translation * new_from_old.scale - (rotation * new_from_old.translation);
            *pose = Pose::new(rotation, translation);
        }
    }

    /// The camera of an image.
    pub fn camera_of(&self, input: &SfmInput, image: usize) -> &dyn CameraModel {
        &self.cameras[input.images[image].group]
    }
}
