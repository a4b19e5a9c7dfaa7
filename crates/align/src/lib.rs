//! Orientation of the multi-epoch block: incremental structure from motion over verified tracks,
//! georeferencing, and the co-registration strategies of docs/design.md behind one trait
//! (`timesift`, `independent`, `chunk`, `msfm`, `stp`, `manual`: [`Method`]).
//!
//! Inside: `model` (input: camera groups, keypoint positions per image, tracks; output:
//! [`Reconstruction`]), `options`, `state` (one reconstruction in progress: track → point table,
//! triangulation of tracks, extension of points to newly oriented images, filtering), `init`
//! (initial pair), `register` (next image and absolute pose), `adjust` (bundle adjustment through
//! `timesift-bundle`), `incremental` (the loop and components), `georef` (similarity to GNSS
//! priors and control points per component, merge, adjustment with the priors, control and
//! check point residuals), `strategy/` (the strategies over a multi-epoch `Block`, one file
//! each, named by [`Method`]; `stp` over a caller-given descriptor matcher, `joined` the
//! optional second look of `timesift`: two epochs' own tie points that the first block puts
//! together and the matcher pairs become inter-epoch ties), `moved` (inter-epoch tie points on
//! surfaces that moved or off the stable ground, split by epoch), `stable_ground` (the
//! caller's stable areas as a grid), `changed` (without them, the regions whose inter-epoch
//! ties differ between epochs on average).
//!
//! Invariants: meets the other stages only through `timesift-core` types (tracks, cameras, poses);
//! reads no file and knows nothing of descriptors (`stp` and `timesift`'s second look ask a [`StableMatcher`]); an epoch is a partition of the images and a
//! reference index, nothing more; every random choice is
//! seeded, so a run is reproducible; the frame of a reconstruction is arbitrary (first image at
//! the origin) until georeferencing.
//!
//! # Example
//!
//! Two surveys of one site flown with `timesift-synth`'s flight planner, their tie points
//! projected exactly, oriented as one block by the `timesift` strategy. Without priors the block
//! stays in a local frame; after one similarity every camera centre is where it was flown.
//!
//! ```
//! use timesift_align::{Block, GeoreferenceInput, SfmImage, SfmInput, SfmOptions, SingleBlock, Strategy};
//! use timesift_core::nalgebra::{Vector2, Vector3};
//! use timesift_core::{BrownCamera, Camera, FeatureIndex, ImageId, SeededRng, Track, TrackElement};
//! use timesift_geometry::{TransformKind, umeyama};
//! use timesift_synth::flight::NadirBlock;
//!
//! let brown = BrownCamera::new(1000, 750, 900.0)?;
//! let camera = Camera::Brown(brown.clone());
//! let flight = NadirBlock {
//!     min: (0.0, 0.0), max: (40.0, 30.0), altitude: 25.0, ground: 0.0,
//!     forward: 0.6, side: 0.4, tilt_sigma: 0.02, position_sigma: 0.3,
//! };
//! let mut rng = SeededRng::new(3);
//! let first = flight.poses(&brown, &mut rng);
//! let second = flight.poses(&brown, &mut rng);
//! let epoch_of: Vec<usize> = first.iter().map(|_| 0).chain(second.iter().map(|_| 1)).collect();
//! let poses = [first, second].concat();
//!
//! // Ground points with 2 m of relief, each a track of the images that see it.
//! let mut keypoints: Vec<Vec<Vector2<f64>>> = vec![Vec::new(); poses.len()];
//! let mut tracks = Vec::new();
//! for _ in 0..2000 {
//!     let x = Vector3::new(
//!         rng.uniform_range(-5.0, 45.0),
//!         rng.uniform_range(-5.0, 35.0),
//!         rng.uniform_range(0.0, 2.0),
//!     );
//!     let mut elements = Vec::new();
//!     for (i, pose) in poses.iter().enumerate() {
//!         let Ok(u) = timesift_core::project_world(&camera, pose, &x) else { continue };
//!         if u.x > 0.0 && u.y > 0.0 && u.x < 1000.0 && u.y < 750.0 {
//!             let feature = FeatureIndex::from(keypoints[i].len());
//!             elements.push(TrackElement { image: ImageId::from(i), feature });
//!             keypoints[i].push(u);
//!         }
//!     }
//!     if elements.len() >= 2 {
//!         tracks.push(Track { elements });
//!     }
//! }
//! let images = keypoints.into_iter().map(|keypoints| SfmImage { group: 0, keypoints });
//! let block = Block {
//!     sfm: SfmInput { cameras: vec![camera], images: images.collect(), tracks, focal: Vec::new() },
//!     ground: GeoreferenceInput { marker_sigma_px: 0.5, ..GeoreferenceInput::default() },
//!     epoch_of,
//!     epoch_names: vec!["2019".into(), "2021".into()],
//!     reference: 0,
//!     stable_ground: None,
//!     natural_points: Vec::new(),
//! };
//!
//! let oriented = SingleBlock::default().orient(&block, &SfmOptions::default())?;
//! assert_eq!(oriented.reconstruction.num_oriented(), poses.len());
//! let ours: Vec<Vector3<f64>> =
//!     oriented.reconstruction.poses.iter().flatten().map(|p| p.center()).collect();
//! let truth: Vec<Vector3<f64>> = poses.iter().map(|p| p.center()).collect();
//! let onto_truth = umeyama(&ours, &truth, None, TransformKind::Similarity)?;
//! for (a, b) in ours.iter().zip(&truth) {
//!     assert!((onto_truth.apply(a) - b).norm() < 1e-4);
//! }
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

#![warn(missing_docs, unnameable_types)]

mod adjust;
mod changed;
mod datum_tilt;
mod error;
mod georef;
mod global;
mod incremental;
mod init;
mod model;
mod moved;
mod options;
mod reference_dem;
mod register;
mod robust;
mod stable_ground;
mod state;
mod strategy;
mod surface;

pub use adjust::{CentrePrior, OffsetPrior};
pub use datum_tilt::{DatumTilt, HeightObservation, datum_tilt};
pub use error::AlignError;
pub use georef::{
    Datum, Diagnostics, EstimatedOffset, GeoreferenceInput, Georeferenced, GroundPoint, Marker,
    PointResidual, georeference, ground_point_residuals,
};
pub use incremental::reconstruct;
pub use model::{FocalSource, Reconstruction, SfmImage, SfmInput, SparsePoint};
pub use options::{
    ChangeDetection, GLOBAL_MAPPER_FROM_IMAGES, Mapper, OutlierBound, ScatterWeighing,
    SelfCalibration, SfmOptions,
};
pub use reference_dem::ReferenceDem;
pub use stable_ground::StableGround;
pub use strategy::{
    Block, ChunkAlignment, DatumControl, GuidedMatch, GuidedQuery, Independent,
    MIN_REFERENCE_IMAGES, ManualStablePoints, Method, NaturalPoint, OfferedTiePoint,
    ProgressiveMerge, SingleBlock, StableMatch, StableMatcher, StableSearch, StableTiePoints,
    Strategy, strategy,
};
pub use surface::{SurfaceFit, SurfaceHeight};
