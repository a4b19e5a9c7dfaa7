//! Settings of incremental structure from motion. Defaults follow COLMAP's mapper where it has an
//! equivalent, with the reasons noted where they differ.

use crate::AlignError;

/// Which intrinsics the bundle adjustments estimate, by parameter name of the camera model
/// (`CameraModel::param_names`), and from when.
#[derive(Debug, Clone, PartialEq)]
pub struct SelfCalibration {
    /// Parameters adjusted in global adjustments once a group has `min_images` oriented images.
    pub parameters: Vec<String>,
    /// Parameters adjusted in the final adjustment of a block (usually a superset: principal
    /// point and decentring need the whole block to be separable from the poses).
    pub final_parameters: Vec<String>,
    /// Oriented images a group needs before its intrinsics are adjusted.
    pub min_images: usize,
    /// Oriented images a group needs before the final parameter set is used (fewer: the
    /// `parameters` set).
    pub final_min_images: usize,
    /// Per camera group (as the input's cameras): parameters held whatever the lists say (a
    /// film camera's radial terms from its certificate). Empty: none.
    pub held: Vec<Vec<String>>,
}

impl Default for SelfCalibration {
    fn default() -> Self {
        let names = |v: &[&str]| v.iter().map(|s| s.to_string()).collect();
        SelfCalibration {
            parameters: names(&["f", "k1", "k2"]),
            final_parameters: names(&["f", "cx", "cy", "k1", "k2", "k3", "p1", "p2"]),
            min_images: 3,
            final_min_images: 10,
            held: Vec::new(),
        }
    }
}

/// Options of [`crate::reconstruct`].
#[derive(Debug, Clone, PartialEq)]
pub struct SfmOptions {
    /// Fewest essential-matrix inliers of the initial pair.
    pub init_min_inliers: usize,
    /// Smallest median triangulation angle of the initial pair, degrees.
    pub init_min_angle_deg: f64,
    /// Candidate pairs evaluated at a time for initialisation, most shared tracks first; further
    /// batches (up to eight in all) only while none passes the full thresholds.
    pub init_max_trials: usize,
    /// Inlier threshold of the two-view and absolute-pose RANSACs, pixels (COLMAP: 4 and 12; the
    /// absolute pose is scored on reprojections of points that carry their own error).
    pub init_max_error_px: f64,
    /// Inlier threshold of absolute-pose RANSAC, pixels.
    pub abs_pose_max_error_px: f64,
    /// Fewest 2-D/3-D inliers to orient an image.
    pub abs_pose_min_inliers: usize,
    /// Smallest inlier share of the 2-D/3-D correspondences to orient an image.
    pub abs_pose_min_inlier_ratio: f64,
    /// Times an image may fail to orient before it is given up (until the next global
    /// adjustment makes more points available).
    pub max_register_trials: usize,
    /// Largest reprojection error of a kept observation, pixels.
    pub max_reprojection_px: f64,
    /// Smallest largest triangulation angle of a kept point, degrees.
    pub min_triangulation_angle_deg: f64,
    /// Oriented images adjusted around each new image (the new one included).
    pub local_adjustment_images: usize,
    /// A global adjustment runs when the oriented images grew by this factor since the last.
    pub global_adjustment_growth: f64,
    /// Intrinsics estimation.
    pub self_calibration: SelfCalibration,
    /// Standard deviation of tie-point measurements, pixels.
    pub tie_point_sigma_px: f64,
    /// Iterations of each global adjustment.
    pub global_iterations: usize,
    /// Iterations of each local adjustment.
    pub local_iterations: usize,
    /// Smallest component reported (images); smaller leftovers stay unoriented.
    pub min_component_images: usize,
    /// An epoch's observations of an inter-epoch tie point that miss it by more than this many
    /// times the block's median reprojection error mark a surface that moved: the point is split
    /// by epoch (strategies that orient epochs together). `f64::INFINITY` keeps every tie.
    pub moved_point_factor: f64,
    /// What the single-block strategies do about ground that changed where the caller gave no
    /// stable ground ([`crate::Block::stable_ground`], which always wins).
    pub change_detection: ChangeDetection,
    /// Whose noise sets the observation outlier bound once a block is adjusted.
    pub outlier_bound: OutlierBound,
    /// Which flights' GNSS priors the final adjustment weighs by their own scatter about their
    /// offset rather than by their stated σ.
    pub scatter_weighing: ScatterWeighing,
    /// `timesift` with a descriptor matcher ([`crate::SingleBlock::matcher`]): after the first
    /// block, tie points of two epochs that the block puts within two ground pixels of each
    /// other and whose descriptors match are joined into inter-epoch ties, and the block is
    /// oriented again with them. Off by default: it doubles the orientation's time for gains
    /// within the spread of the synthetic scenes except on vegetation and film.
    pub join_epoch_ties: bool,
    /// `timesift` with a descriptor matcher ([`crate::SingleBlock::matcher`]): after the first
    /// block, each tie point is projected into the images of the epochs it is not seen in, and
    /// a keypoint within a few pixels whose descriptor clearly matches the point's becomes an
    /// observation of it (module `guided`); the block is oriented again with them. Matching
    /// at the block's own geometry finds ties where the feature matching's ratio test over
    /// whole images fails: ground whose appearance changed between epochs.
    pub guided_epoch_ties: bool,
    /// `timesift` and `msfm`: once the block is georeferenced, each later epoch's own tie
    /// points on stable ground (given, or where they meet the reference epoch's surface once
    /// the block's offset and tilt are removed) get height observations from the surface of
    /// the reference epoch's tie points, and the block is adjusted again (module `surface`):
    /// the epochs are tied across their whole common ground, not only where their features
    /// matched.
    pub surface_ties: bool,
    /// Which structure from motion orients the images before georeferencing (the strategies
    /// that orient every epoch in one block: `timesift`).
    pub mapper: Mapper,
    /// Seed of every RANSAC.
    pub seed: u64,
}

/// Blocks of at least this many images are oriented by the global mapper under
/// [`Mapper::Auto`]: from here on it was the faster on the scale bench (`synth scale-N`: align
/// 85 s against 99 s at 200 images, the check points equal to the millimetre), while the
/// smaller blocks every other bench and test measures keep the incremental mapper they were
/// measured with.
pub const GLOBAL_MAPPER_FROM_IMAGES: usize = 200;

/// Which structure from motion orients a block ([`SfmOptions::mapper`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Mapper {
    /// [`Mapper::Global`] for blocks of at least [`GLOBAL_MAPPER_FROM_IMAGES`] images,
    /// [`Mapper::Incremental`] below.
    #[default]
    Auto,
    /// One image at a time from an initial pair, the block adjusted whenever it grew by
    /// [`SfmOptions::global_adjustment_growth`]: needs nothing but tracks.
    Incremental,
    /// Rotations averaged over every pair at once, centres from the pairs' directions and the
    /// GNSS priors, then a few adjustments of the whole block (module `global`): a handful of
    /// adjustments where the incremental mapper runs tens. Falls back to the incremental
    /// mapper where the priors or the pairs do not suffice.
    Global,
}

/// How a single block finds ground that changed between epochs without stable areas given.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ChangeDetection {
    /// Only the moved-point test ([`SfmOptions::moved_point_factor`]): smooth change below the
    /// noise of one point keeps tying the epochs.
    #[default]
    MovedPointsOnly,
    /// Also regions whose inter-epoch ties, intersected in each epoch apart, differ
    /// significantly on average: their ties stop tying the epochs and the block is adjusted
    /// again, the most significant first, until no region is found (at most six rounds).
    Regional,
}

/// Whose reprojection noise the outlier bound of an adjusted block follows
/// ([`SfmOptions::outlier_bound`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum OutlierBound {
    /// Each camera group's own: a noisier group (scanned film among digital images) keeps the
    /// observations its own noise allows.
    #[default]
    PerGroup,
    /// One bound from every observation of the block (what a single reprojection-error filter
    /// does): a noisier group loses observations its own noise would keep. For comparisons.
    Pooled,
}

/// Which flights' GNSS priors are weighed by their scatter about their offset
/// ([`SfmOptions::scatter_weighing`]), where below the stated σ: a receiver's stated accuracy
/// covers its bias, which the offset carries, and the scatter within a flight is often several
/// times smaller.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ScatterWeighing {
    /// The flights of the images control points are marked in; every flight when no control
    /// point is marked. The other flights keep their stated σ: they are placed through the tie
    /// points, and on `synth orchard` weighing them by their scatter moved the controlled
    /// epoch's datum (`georef::scatter_weighed_flights` has the figures).
    #[default]
    Controlled,
    /// Every flight (before this choice existed): for comparisons.
    All,
    /// No flight: every prior with its stated σ.
    NoFlight,
}

impl Default for SfmOptions {
    fn default() -> Self {
        SfmOptions {
            init_min_inliers: 50,
            init_min_angle_deg: 4.0,
            init_max_trials: 30,
            init_max_error_px: 4.0,
            abs_pose_max_error_px: 8.0,
            abs_pose_min_inliers: 20,
            abs_pose_min_inlier_ratio: 0.25,
            max_register_trials: 2,
            max_reprojection_px: 4.0,
            min_triangulation_angle_deg: 1.5,
            local_adjustment_images: 6,
            global_adjustment_growth: 1.1,
            self_calibration: SelfCalibration::default(),
            tie_point_sigma_px: 1.0,
            global_iterations: 50,
            local_iterations: 25,
            min_component_images: 3,
            moved_point_factor: 5.0,
            change_detection: ChangeDetection::default(),
            outlier_bound: OutlierBound::default(),
            scatter_weighing: ScatterWeighing::default(),
            join_epoch_ties: false,
            guided_epoch_ties: false,
            surface_ties: true,
            mapper: Mapper::default(),
            seed: 0xa1_16e,
        }
    }
}

impl SfmOptions {
    /// Checks every option's domain.
    pub fn validate(&self) -> Result<(), AlignError> {
        let positive = [
            ("init_max_error_px", self.init_max_error_px),
            ("abs_pose_max_error_px", self.abs_pose_max_error_px),
            ("max_reprojection_px", self.max_reprojection_px),
            ("tie_point_sigma_px", self.tie_point_sigma_px),
        ];
        for (name, value) in positive {
            if !(value > 0.0 && value.is_finite()) {
                return Err(AlignError::InvalidOption {
                    name,
                    value,
                    expected: "a positive finite number",
                });
            }
        }
        if !(self.global_adjustment_growth > 1.0) {
            return Err(AlignError::InvalidOption {
                name: "global_adjustment_growth",
                value: self.global_adjustment_growth,
                expected: "a factor above 1",
            });
        }
        if !(self.moved_point_factor > 1.0) {
            return Err(AlignError::InvalidOption {
                name: "moved_point_factor",
                value: self.moved_point_factor,
                expected: "a factor above 1 (infinity keeps every tie)",
            });
        }
        if !(0.0..1.0).contains(&self.abs_pose_min_inlier_ratio) {
            return Err(AlignError::InvalidOption {
                name: "abs_pose_min_inlier_ratio",
                value: self.abs_pose_min_inlier_ratio,
                expected: "a share in [0, 1)",
            });
        }
        if self.init_min_inliers < 8 || self.abs_pose_min_inliers < 4 {
            return Err(AlignError::InvalidOption {
                name: "init_min_inliers / abs_pose_min_inliers",
                value: self.init_min_inliers.min(self.abs_pose_min_inliers) as f64,
                expected: "at least 8 two-view and 4 absolute-pose inliers",
            });
        }
        Ok(())
    }
}
