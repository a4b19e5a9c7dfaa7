//! `project.toml`: the typed configuration of a project. Every option has a default, documented
//! here and in the file `timesift init` writes; unknown keys are errors naming the key.
//!
//! Long module: it is the reference of the file format, every section's keys with their
//! documented defaults and checks in one place, read top to bottom as the file is.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use timesift_align::Method;

use crate::ProjectError;

/// The whole `project.toml`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProjectConfig {
    /// World frame: `"EPSG:<code>"` of a projected CRS, or `"local"`. Default `"local"`.
    #[serde(default = "default_crs")]
    pub crs: String,
    /// The epochs, in chronological order.
    #[serde(default, rename = "epoch")]
    pub epochs: Vec<EpochConfig>,
    /// Where the CSV inputs are.
    #[serde(default)]
    pub inputs: InputsConfig,
    /// Camera-centre priors.
    #[serde(default)]
    pub gnss: GnssConfig,
    /// Orientation options.
    #[serde(default)]
    pub align: AlignConfig,
    /// Dense-matching options.
    #[serde(default)]
    pub dense: DenseConfig,
    /// DEM and orthomosaic options.
    #[serde(default)]
    pub raster: RasterConfig,
    /// Change-detection options.
    #[serde(default)]
    pub change: ChangeConfig,
    /// Slurm settings of `timesift run --executor slurm` (the command line's options win).
    #[serde(default)]
    pub cluster: ClusterConfig,
    /// Known calibrations of camera groups (`[[camera]]`), e.g. from a film camera's
    /// calibration certificate. Default: none (focal length from EXIF or 1.2 × the long side,
    /// refined by self-calibration).
    #[serde(default, rename = "camera")]
    pub cameras: Vec<CameraConfig>,
}

/// One `[[camera]]`: a known calibration of a camera group. The focal length is given either in
/// pixels (`focal_px`) or in millimetres with the pixel size (`focal_mm` and `pixel_mm`, e.g. a
/// calibrated focal length of 152.06 mm and a scan resolution of 0.021 mm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// Camera group: an epoch's name, or the `camera` that epochs name.
    pub name: String,
    /// Calibrated focal length in pixels.
    #[serde(default)]
    pub focal_px: Option<f64>,
    /// Calibrated focal length in millimetres (needs `pixel_mm`).
    #[serde(default)]
    pub focal_mm: Option<f64>,
    /// Pixel size in millimetres: sensor pixel pitch, or the scan resolution of a film.
    #[serde(default)]
    pub pixel_mm: Option<f64>,
    /// Treat the given focal length as nominal, like an EXIF value: held during structure from
    /// motion, then refined at georeferencing where the block determines it (relative σ under
    /// 5 %). Default `false`: a calibrated focal length is held throughout, as a nadir block
    /// cannot tell it from the flying height.
    #[serde(default)]
    pub adjust_focal: bool,
    /// The certificate's radial distortion curve: `[[r_mm, dr_um], ...]`, the displacement
    /// (µm, positive outwards) at each radial distance (mm) from the principal point. Fitted by
    /// the `brown` model's k1, k2, k3 (as many as the curve has points off the centre) and held
    /// throughout, whatever `[align] self_calibration` says. Needs `focal_mm` and `pixel_mm`.
    /// Default: none (radial terms from self-calibration).
    #[serde(default)]
    pub distortion_um: Option<Vec<[f64; 2]>>,
    /// Scanned film: the certificate's principal point, mm, in the frame of `fiducials`.
    /// Default: the centre of the marks' bounding box.
    #[serde(default)]
    pub principal_point_mm: Option<[f64; 2]>,
    /// Scanned film: a PNG of one fiducial mark as it looks in a scan, cut so that its centre
    /// pixel is the mark's centre (path relative to the project directory). Needed with
    /// `fiducials`.
    #[serde(default)]
    pub fiducial_template: Option<String>,
    /// Scanned film: the certificate's fiducial marks (`[camera.fiducials]`: name = [x, y] in
    /// mm, x right, y up, any origin). With them, every scan of the camera is measured
    /// (`timesift fiducials`), given an interior orientation and resampled to the camera's frame
    /// (the marks' bounding box at `pixel_mm`), and the film's edge, marks and data strip are
    /// kept out of matching. Default: none (images used as they are).
    #[serde(default)]
    pub fiducials: Option<std::collections::BTreeMap<String, [f64; 2]>>,
    /// Scanned film: the transform of each scan to the frame, `affine` (the default: shift,
    /// rotation, two scales and shear, which a flatbed scan of shrunk film is) or `projective`
    /// (used for scans with eight marks or more; for scanners whose platen tilts).
    #[serde(default)]
    pub interior_orientation: InteriorOrientationModel,
    /// A PNG of the camera's images as the stages see them (a film camera: its frame, as
    /// `out/fiducials_frame_<camera>.png` shows it) where zero marks pixels that must give no
    /// keypoint and no depth (a lens hood, a drone's legs, a film camera's clock or level left
    /// inside the frame). Combined with the film mask. Default: none.
    #[serde(default)]
    pub mask: Option<String>,
}

/// `[[camera]] interior_orientation`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum InteriorOrientationModel {
    /// Six parameters.
    #[default]
    Affine,
    /// Eight parameters, with eight marks or more (else affine).
    Projective,
}

fn default_crs() -> String {
    "local".to_string()
}

/// Image selection: one glob or path, or a list of them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum ImageSelection {
    /// One glob or path relative to the project directory.
    One(String),
    /// Several globs or paths.
    Many(Vec<String>),
}

impl ImageSelection {
    /// The patterns in order.
    pub fn patterns(&self) -> Vec<&str> {
        match self {
            ImageSelection::One(p) => vec![p.as_str()],
            ImageSelection::Many(v) => v.iter().map(String::as_str).collect(),
        }
    }
}

/// One `[[epoch]]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EpochConfig {
    /// Epoch name (e.g. a date); used in output paths, so no `/`.
    pub name: String,
    /// Images of the epoch: glob(s) or path(s) relative to the project directory. Default
    /// `"images/<name>/*"` (every JPEG, PNG or TIFF there). Globs match image files only; a glob
    /// matching nothing and a listed path that does not exist are errors.
    #[serde(default)]
    pub images: Option<ImageSelection>,
    /// Camera group sharing intrinsics. Default: the epoch's name ("split by epoch").
    #[serde(default)]
    pub camera: Option<String>,
}

/// `[inputs]`: file names relative to the project directory. A file named explicitly must exist;
/// a default name is used when the file is present.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputsConfig {
    /// Ground control points. Default `gcps.csv`.
    pub gcps: Option<String>,
    /// Image measurements of control and check points. Default `markers.csv`.
    pub markers: Option<String>,
    /// Independent check points. Default `checkpoints.csv`.
    pub checkpoints: Option<String>,
    /// Camera-centre priors. Default `gnss.csv`.
    pub gnss: Option<String>,
    /// Stable-area polygons (WKT). Default `stable.csv`.
    pub stable: Option<String>,
    /// Scale bars between named targets (`a,b,distance[,sd]`). Default `scalebars.csv`.
    pub scalebars: Option<String>,
    /// Natural points on stable ground measured in several epochs (`name[,sxy,sz]`), the
    /// control of `method = "manual"`. Default `stable_points.csv`.
    pub stable_points: Option<String>,
    /// Fiducial marks measured by hand in scans (`image,mark,u,v`), which replace the
    /// automatic measurement of those marks. Default `fiducials.csv`.
    pub fiducials: Option<String>,
}

/// `[gnss]`: camera-centre priors.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GnssConfig {
    /// Read EXIF GPS positions as priors when there is no gnss file. Default `true`.
    #[serde(default = "yes")]
    pub exif: bool,
    /// Horizontal standard deviation (m) of priors that give none. Default 5 m (consumer GPS).
    #[serde(default = "default_sxy")]
    pub sxy: f64,
    /// Vertical standard deviation (m) of priors that give none. Default 10 m.
    #[serde(default = "default_sz")]
    pub sz: f64,
    /// Which unknown offsets the priors carry: `epoch` (the default: one per epoch, as a
    /// receiver's bias changes from flight to flight) or `none` (priors taken as unbiased).
    #[serde(default)]
    pub offsets: GnssOffsets,
    /// Which flights' priors are weighed by their own scatter about their offset, where below
    /// the stated σ: `controlled` (the default: the flights of the images that control points
    /// are marked in, every flight when none are), `all` or `none` (every prior with its
    /// stated σ).
    #[serde(default)]
    pub weigh_by_scatter: WeighByScatter,
}

/// `[gnss] weigh_by_scatter`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WeighByScatter {
    /// The flights of the images control points are marked in (every flight without control):
    /// the others are placed by the tie points (`timesift_align::ScatterWeighing::Controlled`
    /// gives the measurements both ways).
    #[default]
    Controlled,
    /// Every flight.
    All,
    /// No flight (`"none"`): every prior with its stated σ.
    #[serde(rename = "none")]
    NoFlight,
}

/// `[gnss] offsets`: the GNSS bias model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GnssOffsets {
    /// One offset per epoch, estimated in the adjustment with a zero-mean prior of the epoch's
    /// stated accuracy.
    #[default]
    Epoch,
    /// No offset: the priors' stated σ must then cover their bias.
    None,
}

fn yes() -> bool {
    true
}
fn default_sxy() -> f64 {
    5.0
}
fn default_sz() -> f64 {
    10.0
}

impl Default for GnssConfig {
    fn default() -> Self {
        GnssConfig {
            exif: true,
            sxy: default_sxy(),
            sz: default_sz(),
            offsets: GnssOffsets::default(),
            weigh_by_scatter: WeighByScatter::default(),
        }
    }
}

/// Feature detector and descriptor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FeatureMethod {
    /// SIFT with RootSIFT descriptors (the default).
    #[default]
    Sift,
    /// Binary LDB descriptors on the same keypoints.
    Ldb,
}

/// Which image pairs the `match` stage matches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PairSelection {
    /// Within an epoch the nearest images by position prior when every image has one, else
    /// every pair; between epochs the nearest images of every other epoch (every image without
    /// priors). The default.
    #[default]
    Auto,
    /// Every pair of images, priors or not.
    Exhaustive,
    /// The `auto` pairs, then only those whose largest-scale keypoints match (plus each image's
    /// best few per epoch): for large blocks without priors, where most pairs do not overlap.
    Preselect,
}

impl PairSelection {
    /// The name in project.toml.
    pub fn name(self) -> &'static str {
        match self {
            PairSelection::Auto => "auto",
            PairSelection::Exhaustive => "exhaustive",
            PairSelection::Preselect => "preselect",
        }
    }
}

/// `[align]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AlignConfig {
    /// Strategy. Default `timesift`.
    #[serde(default)]
    pub method: Method,
    /// Epoch carrying the datum. Default: the first epoch.
    #[serde(default)]
    pub reference_epoch: Option<String>,
    /// Features. Default `sift`.
    #[serde(default)]
    pub features: FeatureMethod,
    /// Which pairs are matched. Default `auto`.
    #[serde(default)]
    pub pair_selection: PairSelection,
    /// Between epochs, each epoch is matched with the reference epoch and with this many
    /// epochs before and after it in `[[epoch]]` order (time order). Default: every other
    /// epoch up to 8 epochs, then 2 either side, so that the pairs per image stay bounded as the
    /// archive grows (a block of 16 epochs would otherwise match every image with 15 others).
    #[serde(default)]
    pub epoch_partners: Option<usize>,
    /// Which structure from motion orients the `timesift` block: `incremental` (one image at a
    /// time), `global` (rotations averaged over every pair, centres from the GNSS priors and
    /// the pairs' directions, a few adjustments of the whole block; falls back to incremental
    /// without priors), `auto` (global from 200 images). Default `auto`.
    #[serde(default)]
    pub mapper: MapperConfig,
    /// Keypoint limit per image. Default 40000.
    #[serde(default = "default_max_keypoints")]
    pub max_keypoints: usize,
    /// Keypoints per image (the largest-scale ones) matched exhaustively first: where they
    /// verify a pair's geometry, every keypoint is then searched near it (along epipolar lines,
    /// or about a homography's transfer for flat ground) instead of against all of the other
    /// image's, about a tenth of the cost; pairs they cannot verify are matched exhaustively.
    /// 0 matches every pair exhaustively. Default 1024.
    #[serde(default = "default_coarse_match_keypoints")]
    pub coarse_match_keypoints: usize,
    /// Tie-point accuracy in pixels (bundle weighting). Default 1.0.
    #[serde(default = "default_tie_px")]
    pub tie_point_accuracy_px: f64,
    /// Marker accuracy in pixels. Default 0.5.
    #[serde(default = "default_marker_px")]
    pub marker_accuracy_px: f64,
    /// Use GCPs in every epoch rather than only in the reference epoch. Default `false`.
    #[serde(default)]
    pub gcps_in_all_epochs: bool,
    /// Which inter-epoch tie points tie the epochs of a single block (`timesift`, `msfm`).
    /// Default `auto`: with stable areas given, only those on them; without, none on ground
    /// the block's own ties show changed.
    #[serde(default)]
    pub inter_epoch_ties: InterEpochTies,
    /// Whose reprojection noise bounds the kept observations once the block is adjusted.
    /// Default `group`: each camera group's own.
    #[serde(default)]
    pub outlier_bound: OutlierBoundConfig,
    /// `timesift`: after the first block, join tie points of two epochs that it puts within
    /// two ground pixels of each other and whose descriptors match into inter-epoch ties, and
    /// orient the block again with them (twice the orientation's time). Default `false`.
    #[serde(default)]
    pub join_epoch_ties: bool,
    /// After the first block, seek each tie point among the keypoints near its projection in
    /// the other epochs' images, and orient the block again with what matches
    /// (`timesift_align::SfmOptions::guided_epoch_ties`). Default `false`.
    #[serde(default)]
    pub guided_epoch_ties: bool,
    /// `timesift`, `msfm`: hold the later epochs' own tie points on stable ground to the
    /// reference epoch's surface by height observations, and adjust the block again
    /// (`timesift_align::SfmOptions::surface_ties`). Default `true`.
    #[serde(default = "yes")]
    pub surface_ties: bool,
    /// The intrinsics the final adjustments estimate, by name (`f`, `cx`, `cy`, `b1`, `b2`,
    /// `k1`…`k4`, `p1`, `p2`), as Metashape's "adjust" list. Default: f, cx, cy, k1, k2, k3,
    /// p1, p2. A calibrated focal length (`[[camera]]`) stays held whatever the list says.
    #[serde(default)]
    pub self_calibration: Option<Vec<String>>,
    /// `timesift`, `msfm`: a reference DEM (a single-band GeoTIFF, relative to the project
    /// folder, in the project's CRS or any EPSG CRS it can be transformed from; heights in the
    /// project's vertical datum). Every epoch's tie points on stable ground (stable.csv, or
    /// where they meet it) get height observations from it on its tangent plane, so that a
    /// block without control lands on it, given a datum to start from (camera-centre priors to
    /// some metres). Default: none.
    #[serde(default)]
    pub reference_dem: Option<PathBuf>,
    /// Standard deviation of one height of `reference_dem`, metres. Default 0.5.
    #[serde(default = "default_reference_dem_sigma")]
    pub reference_dem_sigma: f64,
}

fn default_reference_dem_sigma() -> f64 {
    0.5
}

/// `[align] mapper`: which structure from motion orients the block.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MapperConfig {
    /// `global` for blocks of 200 images and more, `incremental` below
    /// (`timesift_align::Mapper::Auto`).
    #[default]
    Auto,
    /// One image at a time from an initial pair (`timesift_align::Mapper::Incremental`).
    Incremental,
    /// Rotation averaging and GNSS-seeded centres, then a few adjustments of the whole block
    /// (`timesift_align::Mapper::Global`).
    Global,
}

/// `[align] outlier_bound`: whose noise the observation outlier bound (4 σ) follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum OutlierBoundConfig {
    /// Each camera group's own σ: scanned film among digital images keeps the observations its
    /// own noise allows.
    #[default]
    Group,
    /// One σ of every observation of the block, as a single reprojection-error filter gives.
    Pooled,
}

/// `[align] inter_epoch_ties`: which tie points may join the epochs of a single block.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum InterEpochTies {
    /// Only tie points on the stable areas (`stable.csv`) when the project has them; without
    /// them, none on ground that the block's own ties show changed: intersected in each epoch
    /// apart, the ties of a region differ significantly on average (decimetres of smooth
    /// change that no single point shows). Ground that changed by less than one point's noise
    /// (accreting sand, thinning ice, a creeping slope) would otherwise bend the block and
    /// flatten the change.
    #[default]
    Auto,
    /// Only tie points on the stable areas when the project has them; every tie point
    /// otherwise.
    Stable,
    /// Every tie point that passed the moved-point test.
    All,
}

fn default_max_keypoints() -> usize {
    40_000
}
fn default_coarse_match_keypoints() -> usize {
    timesift_matching::StagedOptions::default().coarse_keypoints
}
fn default_tie_px() -> f64 {
    1.0
}
fn default_marker_px() -> f64 {
    0.5
}

/// Epochs up to which every pair of epochs is matched when `epoch_partners` is not given.
pub const ALL_EPOCH_PAIRS_UP_TO: usize = 8;
/// Epochs matched either side of each beyond [`ALL_EPOCH_PAIRS_UP_TO`] epochs.
pub const DEFAULT_EPOCH_PARTNERS: usize = 2;

impl AlignConfig {
    /// The epochs either side of each that it is matched with, in a block of `epochs` epochs;
    /// `None`: every other epoch.
    pub fn epoch_partners(&self, epochs: usize) -> Option<usize> {
        match self.epoch_partners {
            Some(n) => Some(n),
            None if epochs <= ALL_EPOCH_PAIRS_UP_TO => None,
            None => Some(DEFAULT_EPOCH_PARTNERS),
        }
    }
}

impl Default for AlignConfig {
    fn default() -> Self {
        AlignConfig {
            method: Method::default(),
            reference_epoch: None,
            features: FeatureMethod::default(),
            pair_selection: PairSelection::default(),
            epoch_partners: None,
            mapper: MapperConfig::default(),
            max_keypoints: default_max_keypoints(),
            coarse_match_keypoints: default_coarse_match_keypoints(),
            tie_point_accuracy_px: default_tie_px(),
            marker_accuracy_px: default_marker_px(),
            gcps_in_all_epochs: false,
            inter_epoch_ties: InterEpochTies::default(),
            outlier_bound: OutlierBoundConfig::default(),
            join_epoch_ties: false,
            guided_epoch_ties: false,
            surface_ties: true,
            self_calibration: None,
            reference_dem: None,
            reference_dem_sigma: default_reference_dem_sigma(),
        }
    }
}

/// `[dense]`: multi-view stereo per epoch on the frozen orientation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DenseConfig {
    /// Resolution: 1 (full), 2 (half, Metashape's "high"), 4 or 8. Default 2.
    #[serde(default = "default_dense_level")]
    pub level: u32,
    /// Match again at twice the resolution (half the level) where matching at the level is
    /// poor: a high matching cost, or a surface that bends within a pixel's reach (tree
    /// crowns, boulders, edges), which a window of the level spans with more than one surface.
    /// Flat ground keeps the level's depths and density. No effect at level 1. Default `true`.
    #[serde(default = "yes")]
    pub refine: bool,
    /// Most source views per image (matched with it; the views that see parts of its field
    /// that the best-scored ones miss come first). Filtering and fusion check its depths
    /// against up to twice as many overlapping views. Default 8.
    #[serde(default = "default_max_sources")]
    pub max_sources: usize,
    /// Least sources that must agree with a depth for it to be kept. Default 2.
    #[serde(default = "default_min_views")]
    pub min_views: usize,
    /// Least images a fused point is made from. Default 3.
    #[serde(default = "default_min_images")]
    pub min_images: usize,
    /// Where fewer than `min_views` neighbours, or `min_images` images, have a point in their
    /// field at all (a block's edges, ground that only two images see), keep it when every one
    /// that has agrees (at least one neighbour, two images). Ground that a third view has in its
    /// field but does not see (occlusion) keeps the strict counts. Default `false`: a depth
    /// that only two images agree on has no third view to catch an orientation error or film
    /// grain. Measured (level 2): on `rendered-mar` it fills the DEM's cells that only two
    /// cameras see (true cameras: 190 → 2 holes on 20180925, 90 → 41 on 20190205; align-stage
    /// cameras 188 → 4, 92 → 61) at the same NMAD; on `landslide` with the align stage's
    /// cameras the cloud's 90th percentile error rises from 0.77-0.78 to 0.87-0.92 GSD (true
    /// cameras ±0.01), on `synth archival` (film, 60 % / 30 % overlap: much of the ground in two
    /// images only) from 0.33-0.49 to 0.44-0.76 GSD with the true cameras.
    #[serde(default)]
    pub fill_edges: bool,
    /// Half-size of the matching window, pixels. Default 5 (11 × 11, sampled every other pixel,
    /// its four corners left out: 32 samples).
    #[serde(default = "default_window_radius")]
    pub window_radius: usize,
    /// Intensity σ (0–1) of the matching window's bilateral weights: how much a window sample
    /// of another colour than the centre counts. Smaller keeps a depth edge from spreading
    /// into weakly textured ground beside it (a roof's depth into its shadow). Default (unset):
    /// [`SIGMA_COLOR_DIGITAL`] for digital images, [`SIGMA_COLOR_FILM`] for film scans, whose
    /// grain makes two samples of one surface differ by more.
    #[serde(default)]
    pub sigma_color: Option<f32>,
    /// PatchMatch iterations of the photometric passes. Default 3.
    #[serde(default = "default_photometric_iterations")]
    pub iterations: usize,
    /// PatchMatch iterations of the geometric-consistency passes. Default 2.
    #[serde(default = "default_geometric_iterations")]
    pub geometric_iterations: usize,
    /// PatchMatch iterations of the match at twice the resolution (`refine`), and at most as
    /// many of its geometric pass. Default 3. One takes 1.3–1.7 times less CPU for the whole
    /// stage where much is refined (`orchard`, `archival`) at the same accuracy on open
    /// ground, but measures narrow tree crowns less well.
    #[serde(default = "default_refine_iterations")]
    pub refine_iterations: usize,
    /// Largest matching cost (1 − NCC) of a kept depth. Default 0.6 for digital images, 0.75
    /// for film scans (their grain raises every window's cost).
    pub max_cost: Option<f32>,
    /// Pixels exactly black in every channel are no-data (scan borders). Default `true`.
    #[serde(default = "yes")]
    pub black_is_nodata: bool,
}

fn default_dense_level() -> u32 {
    2
}
fn default_max_sources() -> usize {
    8
}
fn default_min_views() -> usize {
    2
}
fn default_min_images() -> usize {
    3
}
fn default_window_radius() -> usize {
    5
}
/// The bilateral σ of digital images by default. Against 0.1, on the synthetic scenes (true
/// cameras): `campus`'s DEM mean error on textured land +0.15…+0.36 → +0.02…+0.05 GSD (a
/// roof's depth no longer spills into its shadow), `orchard`'s 90th percentile cloud error
/// 0.63–0.65 → 0.50–0.52 GSD, completeness ≥ 90.6 % on every scene. The price is on smooth
/// man-made surfaces: on `lund` (real street, plain plaster facades) the cloud has 146,000
/// points against 224,000 at 0.1, each as consistent (96.2 % within 1 px in ≥ 3 images) — set
/// 0.1 there.
pub const SIGMA_COLOR_DIGITAL: f32 = 0.04;
/// The bilateral σ of film scans by default: on `synth archival` 0.04 instead costs 1–16
/// points of completeness (1971: 76.0 → 60.5 %), the grain's differences within one surface
/// counting as edges.
pub const SIGMA_COLOR_FILM: f32 = 0.1;
fn default_photometric_iterations() -> usize {
    3
}
fn default_geometric_iterations() -> usize {
    2
}
fn default_refine_iterations() -> usize {
    3
}
/// The largest kept cost of digital images by default.
pub const MAX_COST_DIGITAL: f32 = 0.6;
/// The largest kept cost of film scans by default. A scan's grain raises every window's cost,
/// most at the refinement's twice-the-level resolution: on `synth archival` (true cameras) 0.6
/// left 86.6 / 92.9 / 97.7 / 99.1 % of the epochs complete, 0.75 95.4 / 97.2 / 99.0 / 99.6 %
/// at the same median error and a 90th percentile within +0.02 GSD (0.9: 98.1-99.7 %, +0.03).
pub const MAX_COST_FILM: f32 = 0.75;

impl Default for DenseConfig {
    fn default() -> Self {
        DenseConfig {
            level: default_dense_level(),
            refine: true,
            max_sources: default_max_sources(),
            min_views: default_min_views(),
            min_images: default_min_images(),
            fill_edges: false,
            window_radius: default_window_radius(),
            sigma_color: None,
            iterations: default_photometric_iterations(),
            geometric_iterations: default_geometric_iterations(),
            refine_iterations: default_refine_iterations(),
            max_cost: None,
            black_is_nodata: true,
        }
    }
}

impl DenseConfig {
    /// Lighter matching for the demo and the strategy benchmark, where minutes matter more than
    /// the last detail: 5 sources, 2 photometric and 1 geometric iteration (defaults 8, 3, 2),
    /// no refinement at twice the resolution. On the demo scene it takes 2.4 times less time,
    /// for region volumes within a few percent of the defaults' (measured before refinement
    /// existed).
    pub fn quick() -> DenseConfig {
        DenseConfig {
            refine: false,
            max_sources: 5,
            iterations: 2,
            geometric_iterations: 1,
            ..DenseConfig::default()
        }
    }

    /// The options that differ from the defaults, as `key value` pairs (for printed summaries).
    pub fn differences(&self) -> String {
        let d = DenseConfig::default();
        let mut parts = Vec::new();
        // `key value (default d)` for every option off its default.
        for (key, value, default) in [
            ("level", self.level as usize, d.level as usize),
            ("max_sources", self.max_sources, d.max_sources),
            ("min_views", self.min_views, d.min_views),
            ("min_images", self.min_images, d.min_images),
            ("window_radius", self.window_radius, d.window_radius),
            ("iterations", self.iterations, d.iterations),
            (
                "geometric_iterations",
                self.geometric_iterations,
                d.geometric_iterations,
            ),
            (
                "refine_iterations",
                self.refine_iterations,
                d.refine_iterations,
            ),
        ] {
            if value != default {
                parts.push(format!("{key} {value} (default {default})"));
            }
        }
        for (key, value, default) in [
            ("refine", self.refine, d.refine),
            ("fill_edges", self.fill_edges, d.fill_edges),
            ("black_is_nodata", self.black_is_nodata, d.black_is_nodata),
        ] {
            if value != default {
                parts.push(format!("{key} {value} (default {default})"));
            }
        }
        if let Some(sigma) = self.sigma_color {
            parts.push(format!(
                "sigma_color {sigma} (default {SIGMA_COLOR_DIGITAL} digital, {SIGMA_COLOR_FILM} film)"
            ));
        }
        if let Some(cost) = self.max_cost {
            parts.push(format!(
                "max_cost {cost} (default {MAX_COST_DIGITAL} digital, {MAX_COST_FILM} film)"
            ));
        }
        if parts.is_empty() {
            "defaults".into()
        } else {
            parts.join(", ")
        }
    }

    /// The bilateral σ of an epoch's images: the option when set, else the default of their
    /// kind.
    pub fn sigma_color(&self, images: ImageKind) -> f32 {
        self.sigma_color
            .unwrap_or(images.pick(SIGMA_COLOR_DIGITAL, SIGMA_COLOR_FILM))
    }

    /// The largest kept cost of an epoch's images: the option when set, else the default of
    /// their kind.
    pub fn max_cost(&self, images: ImageKind) -> f32 {
        self.max_cost
            .unwrap_or(images.pick(MAX_COST_DIGITAL, MAX_COST_FILM))
    }

    /// The dense crate's options for an epoch of `images`.
    pub fn options(&self, images: ImageKind) -> timesift_dense::DenseOptions {
        let mut o = timesift_dense::DenseOptions::default();
        o.plan.level = self.level;
        o.plan.refine = self.refine;
        o.plan.max_sources = self.max_sources;
        o.patchmatch.window_radius = self.window_radius;
        o.patchmatch.sigma_color = self.sigma_color(images);
        o.patchmatch.photometric_iterations = self.iterations;
        o.patchmatch.geometric_iterations = self.geometric_iterations;
        o.patchmatch.refine_iterations = self.refine_iterations;
        o.filter.min_views = self.min_views;
        o.filter.max_cost = self.max_cost(images);
        o.fusion.min_images = self.min_images;
        o.filter.fill_edges = self.fill_edges;
        o.fusion.fill_edges = self.fill_edges;
        o.black_is_nodata = self.black_is_nodata;
        o
    }
}

/// What an epoch's images are, for the defaults that depend on it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ImageKind {
    /// Digital photographs.
    Digital,
    /// Scanned film (a camera group with fiducial marks).
    FilmScan,
}

impl ImageKind {
    /// `digital` or `film`, whichever default is this kind's.
    fn pick<T>(self, digital: T, film: T) -> T {
        match self {
            ImageKind::Digital => digital,
            ImageKind::FilmScan => film,
        }
    }
}

/// A cell size: `"auto"` or metres.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(try_from = "toml::Value", into = "toml::Value")]
pub enum CellSize {
    /// Derived from the epochs' ground sample distances.
    #[default]
    Auto,
    /// Metres.
    Metres(f64),
}

impl TryFrom<toml::Value> for CellSize {
    type Error = String;
    fn try_from(v: toml::Value) -> Result<Self, String> {
        match v {
            toml::Value::String(s) if s == "auto" => Ok(CellSize::Auto),
            toml::Value::Float(m) if m > 0.0 && m.is_finite() => Ok(CellSize::Metres(m)),
            toml::Value::Integer(m) if m > 0 => Ok(CellSize::Metres(m as f64)),
            other => Err(format!(
                "expected \"auto\" or a positive number of metres, found {other}"
            )),
        }
    }
}

impl From<CellSize> for toml::Value {
    fn from(c: CellSize) -> toml::Value {
        match c {
            CellSize::Auto => toml::Value::String("auto".into()),
            CellSize::Metres(m) => toml::Value::Float(m),
        }
    }
}

impl CellSize {
    /// Metres, `None` for `auto`.
    pub fn metres(self) -> Option<f64> {
        match self {
            CellSize::Auto => None,
            CellSize::Metres(m) => Some(m),
        }
    }
}

/// The extent of the project's lattice.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(try_from = "toml::Value", into = "toml::Value")]
pub enum Extent {
    /// Everything any epoch covers.
    #[default]
    Union,
    /// What every epoch covers.
    Intersection,
    /// `[xmin, ymin, xmax, ymax]` in the project's CRS.
    Bounds([f64; 4]),
}

impl TryFrom<toml::Value> for Extent {
    type Error = String;
    fn try_from(v: toml::Value) -> Result<Self, String> {
        let expected = "expected \"union\", \"intersection\" or [xmin, ymin, xmax, ymax]";
        match v {
            toml::Value::String(s) if s == "union" => Ok(Extent::Union),
            toml::Value::String(s) if s == "intersection" => Ok(Extent::Intersection),
            toml::Value::Array(a) if a.len() == 4 => {
                let mut b = [0.0; 4];
                for (k, x) in a.iter().enumerate() {
                    b[k] = match x {
                        toml::Value::Float(f) => *f,
                        toml::Value::Integer(i) => *i as f64,
                        _ => return Err(format!("{expected}, found {x}")),
                    };
                }
                if !(b.iter().all(|v| v.is_finite()) && b[2] > b[0] && b[3] > b[1]) {
                    return Err(format!("{expected} with xmin < xmax and ymin < ymax"));
                }
                Ok(Extent::Bounds(b))
            }
            other => Err(format!("{expected}, found {other}")),
        }
    }
}

impl From<Extent> for toml::Value {
    fn from(e: Extent) -> toml::Value {
        match e {
            Extent::Union => toml::Value::String("union".into()),
            Extent::Intersection => toml::Value::String("intersection".into()),
            Extent::Bounds(b) => toml::Value::Array(b.iter().map(|v| (*v).into()).collect()),
        }
    }
}

/// How a DEM cell's height is made from the dense cloud's points.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DemMethod {
    /// Median of the cell's points (the default).
    #[default]
    Median,
    /// Highest point: a surface model of tall objects.
    Max,
    /// Inverse-distance mean within `idw_radius`.
    Idw,
}

/// `[raster]`: the project's lattice, the `dem` and `ortho` stages.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RasterConfig {
    /// DEM cell, m, or `"auto"` (default): 2 × the coarsest epoch's GSD, rounded to 1, 2, 2.5
    /// or 5 × 10ⁿ.
    #[serde(default)]
    pub dem_cell: CellSize,
    /// Ortho cell, m, or `"auto"` (default): the finest epoch's GSD as an integer fraction of
    /// the DEM cell.
    #[serde(default)]
    pub ortho_cell: CellSize,
    /// `"union"` (default), `"intersection"` or `[xmin, ymin, xmax, ymax]`.
    #[serde(default)]
    pub extent: Extent,
    /// `median` (default), `max` or `idw`.
    #[serde(default)]
    pub dem_method: DemMethod,
    /// Search radius of `idw`, in DEM cells. Default 1.5.
    #[serde(default = "default_idw_radius")]
    pub idw_radius: f64,
    /// Least points per cell (or within the `idw` radius). Default 1.
    #[serde(default = "default_min_points")]
    pub min_points: usize,
    /// Holes up to this many cells across are interpolated (and marked in `dem_filled.tif`).
    /// Default 4.
    #[serde(default = "default_max_gap")]
    pub max_gap: usize,
    /// Feathering half-width across ortho seams, DEM cells. Default 2.
    #[serde(default = "default_feather")]
    pub feather: usize,
    /// Sweeps that move ortho seams to where the images agree. Default 3.
    #[serde(default = "default_seam_sweeps")]
    pub seam_sweeps: usize,
    /// Per-image gains fitted on the overlaps. Default `true`.
    #[serde(default = "yes")]
    pub gain_compensation: bool,
}

fn default_idw_radius() -> f64 {
    1.5
}
fn default_min_points() -> usize {
    1
}
fn default_max_gap() -> usize {
    4
}
fn default_feather() -> usize {
    2
}
fn default_seam_sweeps() -> usize {
    3
}

impl Default for RasterConfig {
    fn default() -> Self {
        RasterConfig {
            dem_cell: CellSize::Auto,
            ortho_cell: CellSize::Auto,
            extent: Extent::Union,
            dem_method: DemMethod::Median,
            idw_radius: default_idw_radius(),
            min_points: default_min_points(),
            max_gap: default_max_gap(),
            feather: default_feather(),
            seam_sweeps: default_seam_sweeps(),
            gain_compensation: true,
        }
    }
}

impl RasterConfig {
    /// The lattice options.
    pub fn grid_options(
        &self,
    ) -> Result<timesift_raster::GridOptions, timesift_raster::RasterError> {
        let extent = match self.extent {
            Extent::Union => timesift_raster::ExtentRule::Union,
            Extent::Intersection => timesift_raster::ExtentRule::Intersection,
            Extent::Bounds(b) => timesift_raster::ExtentRule::Explicit(
                timesift_raster::Bounds::new(b[0], b[1], b[2], b[3])?,
            ),
        };
        Ok(timesift_raster::GridOptions {
            dem_cell: self.dem_cell.metres(),
            ortho_cell: self.ortho_cell.metres(),
            extent,
        })
    }

    /// The gridding options for a DEM of `cell` metres.
    pub fn dem_options(&self, cell: f64) -> timesift_raster::DemOptions {
        let height = match self.dem_method {
            DemMethod::Median => timesift_raster::CellHeight::Median,
            DemMethod::Max => timesift_raster::CellHeight::Max,
            DemMethod::Idw => timesift_raster::CellHeight::InverseDistance {
                radius: self.idw_radius * cell,
                power: 2.0,
            },
        };
        timesift_raster::DemOptions {
            height,
            min_points: self.min_points,
            max_gap: self.max_gap,
        }
    }

    /// The orthomosaic options for `factor` ortho cells per DEM cell.
    pub fn ortho_options(
        &self,
        factor: usize,
        black_is_nodata: bool,
    ) -> timesift_raster::OrthoOptions {
        timesift_raster::OrthoOptions {
            factor,
            feather: self.feather,
            seam_sweeps: self.seam_sweeps,
            gain_compensation: self.gain_compensation,
            black_is_nodata,
            ..timesift_raster::OrthoOptions::default()
        }
    }
}

/// Which epochs the `change` stage compares.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ChangePairs {
    /// Each epoch with the next one (the default).
    #[default]
    Consecutive,
    /// Each epoch with the reference epoch.
    Reference,
}

/// DEM co-registration before differencing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Coregistration {
    /// None: Time-SIFT products share one frame by construction (the default).
    #[default]
    None,
    /// Vertical shift only, from the stable areas.
    Vertical,
    /// Nuth & Kääb horizontal and vertical shift, from the stable areas.
    NuthKaab,
}

/// `[change]`: the `change` stage (and defaults of `timesift compare`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChangeConfig {
    /// Epoch pairs. Default `consecutive`.
    #[serde(default)]
    pub pairs: ChangePairs,
    /// DEM co-registration. Default `none`.
    #[serde(default)]
    pub coregistration: Coregistration,
    /// M3C2 normal radius, m. Default 2.0.
    #[serde(default = "default_normal_radius")]
    pub normal_radius: f64,
    /// M3C2 cylinder radius, m. Default 1.0.
    #[serde(default = "default_cylinder_radius")]
    pub cylinder_radius: f64,
    /// M3C2 half-length of the cylinder, m. Default 5.0.
    #[serde(default = "default_max_depth")]
    pub max_depth: f64,
    /// Spacing of M3C2 core points, m. Default 1.0.
    #[serde(default = "default_core_spacing")]
    pub core_spacing: f64,
    /// Registration error added to the M3C2 LoD, m. Default 0.
    #[serde(default)]
    pub registration_error: f64,
}

fn default_normal_radius() -> f64 {
    2.0
}
fn default_cylinder_radius() -> f64 {
    1.0
}
fn default_max_depth() -> f64 {
    5.0
}
fn default_core_spacing() -> f64 {
    1.0
}

impl Default for ChangeConfig {
    fn default() -> Self {
        ChangeConfig {
            pairs: ChangePairs::default(),
            coregistration: Coregistration::default(),
            normal_radius: default_normal_radius(),
            cylinder_radius: default_cylinder_radius(),
            max_depth: default_max_depth(),
            core_spacing: default_core_spacing(),
            registration_error: 0.0,
        }
    }
}

/// Line (1-based) of a byte offset in a text.
fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}

impl ProjectConfig {
    /// Parses `project.toml` text; errors name the file and line, and the key for unknown or
    /// mistyped keys.
    pub fn parse(path: &Path, text: &str) -> Result<Self, ProjectError> {
        let config: ProjectConfig = toml::from_str(text).map_err(|e| {
            let line = e.span().map(|s| line_of(text, s.start)).unwrap_or(1);
            let mut message = e.message().trim().replace('\n', " ");
            // A bad value: name its key (serde's message only names the value).
            let key = text
                .lines()
                .nth(line - 1)
                .and_then(|l| l.split_once('='))
                .map(|(k, _)| k.trim())
                .filter(|k| !k.is_empty() && !k.starts_with('#') && !message.contains(k));
            if let Some(key) = key {
                message = format!("`{key}`: {message}");
            }
            ProjectError::Reference {
                path: path.to_path_buf(),
                line,
                message,
            }
        })?;
        config.check_numbers(path)?;
        config.check_dense_and_raster(path)?;
        Ok(config)
    }

    /// Accuracies, radii and the registration error are positive (or ≥ 0) and finite.
    fn check_numbers(&self, path: &Path) -> Result<(), ProjectError> {
        let config = self;
        let positive = [
            ("gnss.sxy", config.gnss.sxy),
            ("gnss.sz", config.gnss.sz),
            (
                "align.tie_point_accuracy_px",
                config.align.tie_point_accuracy_px,
            ),
            ("align.marker_accuracy_px", config.align.marker_accuracy_px),
            (
                "align.reference_dem_sigma",
                config.align.reference_dem_sigma,
            ),
            ("change.normal_radius", config.change.normal_radius),
            ("change.cylinder_radius", config.change.cylinder_radius),
            ("change.max_depth", config.change.max_depth),
            ("change.core_spacing", config.change.core_spacing),
            ("raster.idw_radius", config.raster.idw_radius),
        ];
        for (key, value) in positive {
            if !(value > 0.0 && value.is_finite()) {
                return Err(ProjectError::config(
                    path,
                    key,
                    format!("expected a positive number, found {value}"),
                ));
            }
        }
        let e = config.change.registration_error;
        if !(e >= 0.0 && e.is_finite()) {
            return Err(ProjectError::config(
                path,
                "change.registration_error",
                format!("expected a number ≥ 0, found {e}"),
            ));
        }
        Ok(())
    }

    /// `[dense]` and `[raster]` counts within their ranges, the dense level a power of two up
    /// to 8, the keypoint budget positive.
    fn check_dense_and_raster(&self, path: &Path) -> Result<(), ProjectError> {
        let config = self;
        let dense = &config.dense;
        if !matches!(dense.level, 1 | 2 | 4 | 8) {
            return Err(ProjectError::config(
                path,
                "dense.level",
                format!("expected 1, 2, 4 or 8, found {}", dense.level),
            ));
        }
        for (key, value, range) in [
            ("dense.max_sources", dense.max_sources, 1..=32),
            ("dense.min_views", dense.min_views, 1..=32),
            ("dense.min_images", dense.min_images, 2..=1000),
            ("dense.window_radius", dense.window_radius, 2..=7),
            ("dense.iterations", dense.iterations, 1..=20),
            (
                "dense.geometric_iterations",
                dense.geometric_iterations,
                0..=20,
            ),
            ("raster.min_points", config.raster.min_points, 1..=10_000),
            ("raster.max_gap", config.raster.max_gap, 0..=1000),
            ("raster.feather", config.raster.feather, 0..=50),
            ("raster.seam_sweeps", config.raster.seam_sweeps, 0..=50),
        ] {
            if !range.contains(&value) {
                return Err(ProjectError::config(
                    path,
                    key,
                    format!(
                        "expected {} to {}, found {value}",
                        range.start(),
                        range.end()
                    ),
                ));
            }
        }
        if let Some(sigma) = dense.sigma_color.filter(|s| !(*s > 0.0 && *s <= 1.0)) {
            return Err(ProjectError::config(
                path,
                "dense.sigma_color",
                format!("expected an intensity σ in (0, 1], found {sigma}"),
            ));
        }
        if let Some(cost) = dense.max_cost.filter(|c| !(*c > 0.0 && *c <= 2.0)) {
            return Err(ProjectError::config(
                path,
                "dense.max_cost",
                format!("expected a cost in (0, 2], found {cost}"),
            ));
        }
        if config.align.max_keypoints == 0 {
            return Err(ProjectError::config(
                path,
                "align.max_keypoints",
                "expected a positive count",
            ));
        }
        Ok(())
    }

    /// Reads and parses `project.toml`.
    pub fn read(path: &Path) -> Result<Self, ProjectError> {
        let text = timesift_io::fsutil::read_text(path)?;
        Self::parse(path, &text)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A one-epoch project whose `[section]` holds `lines`.
    fn parse_section(section: &str, lines: &str) -> Result<ProjectConfig, ProjectError> {
        let text =
            format!("[[epoch]]\nname = \"a\"\nimages = \"images/a/*\"\n\n[{section}]\n{lines}\n");
        ProjectConfig::parse(Path::new("project.toml"), &text)
    }

    fn parse(raster: &str) -> Result<ProjectConfig, ProjectError> {
        parse_section("raster", raster)
    }

    #[test]
    fn raster_keys_as_init_documents_them_are_the_defaults() {
        // The commented [raster] lines `timesift init` writes, uncommented.
        let documented = "dem_cell = \"auto\"\northo_cell = \"auto\"\nextent = \"union\"\n\
                          dem_method = \"median\"\nidw_radius = 1.5\nmin_points = 1\n\
                          max_gap = 4\nfeather = 2\nseam_sweeps = 3\ngain_compensation = true";
        assert_eq!(parse(documented).unwrap().raster, RasterConfig::default());
        let c = parse("dem_cell = 0.5\northo_cell = 0.1\nextent = [0, 1, 10.5, 20]").unwrap();
        assert_eq!(c.raster.dem_cell, CellSize::Metres(0.5));
        assert_eq!(c.raster.ortho_cell, CellSize::Metres(0.1));
        assert_eq!(c.raster.extent, Extent::Bounds([0.0, 1.0, 10.5, 20.0]));
    }

    #[test]
    fn weigh_by_scatter_defaults_to_the_controlled_flights_and_names_its_values() {
        let with_gnss = |line: &str| parse_section("gnss", line);
        assert_eq!(
            with_gnss("").unwrap().gnss.weigh_by_scatter,
            WeighByScatter::Controlled
        );
        for (value, expected) in [
            ("controlled", WeighByScatter::Controlled),
            ("all", WeighByScatter::All),
            ("none", WeighByScatter::NoFlight),
        ] {
            let line = format!("weigh_by_scatter = \"{value}\"");
            assert_eq!(with_gnss(&line).unwrap().gnss.weigh_by_scatter, expected);
        }
        let e = with_gnss("weigh_by_scatter = \"epoch\"")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("weigh_by_scatter") && e.contains("controlled") && e.contains("none"),
            "{e}"
        );
    }

    #[test]
    fn bad_raster_values_name_their_key() {
        for (line, key, what) in [
            ("dem_cell = \"fine\"", "dem_cell", "auto"),
            ("dem_cell = -1.0", "dem_cell", "positive"),
            ("extent = [3, 0, 1, 5]", "extent", "xmin < xmax"),
            ("extent = \"all\"", "extent", "intersection"),
            ("dem_method = \"mean\"", "dem_method", "median"),
            ("max_gap = 5000", "raster.max_gap", "0 to 1000"),
            ("idw_radius = 0.0", "raster.idw_radius", "positive"),
            ("cell = 1.0", "cell", "unknown field"),
        ] {
            let e = parse(line).unwrap_err().to_string();
            assert!(e.contains(key) && e.contains(what), "{line}: {e}");
            assert!(!e.contains('\n'), "{e}");
        }
    }

    #[test]
    fn defaults_by_image_kind_reach_the_matcher_and_bad_values_name_their_key() {
        let with_dense = |line: &str| parse_section("dense", line);
        // Unset, digital images and film scans get their own defaults; a set value is used
        // for both.
        let unset = DenseConfig::default();
        assert_eq!(unset.differences(), "defaults");
        type Getter = fn(&DenseConfig, ImageKind) -> f32;
        let sigma: Getter = |c, kind| c.options(kind).patchmatch.sigma_color;
        let cost: Getter = |c, kind| c.options(kind).filter.max_cost;
        for (key, option, digital, film, value) in [
            (
                "sigma_color",
                sigma,
                SIGMA_COLOR_DIGITAL,
                SIGMA_COLOR_FILM,
                0.07,
            ),
            ("max_cost", cost, MAX_COST_DIGITAL, MAX_COST_FILM, 0.5),
        ] {
            assert_eq!(option(&unset, ImageKind::Digital), digital, "{key}");
            assert_eq!(option(&unset, ImageKind::FilmScan), film, "{key}");
            let set = with_dense(&format!("{key} = {value}")).unwrap();
            assert_eq!(option(&set.dense, ImageKind::Digital), value, "{key}");
            assert_eq!(option(&set.dense, ImageKind::FilmScan), value, "{key}");
            assert!(set.dense.differences().contains(&format!("{key} {value}")));
        }
        // fill_edges reaches the filter and the fusion alike, off unless set.
        for (line, value) in [("", false), ("fill_edges = true", true)] {
            let set = with_dense(line).unwrap();
            for kind in [ImageKind::Digital, ImageKind::FilmScan] {
                let o = set.dense.options(kind);
                assert_eq!((o.filter.fill_edges, o.fusion.fill_edges), (value, value));
            }
            assert_eq!(set.dense.differences().contains("fill_edges true"), value);
        }
        for (bad, key, range) in [
            ("max_cost = 0.0", "dense.max_cost", "(0, 2]"),
            ("max_cost = 2.5", "dense.max_cost", "(0, 2]"),
            ("sigma_color = 0.0", "dense.sigma_color", "(0, 1]"),
            ("sigma_color = 1.5", "dense.sigma_color", "(0, 1]"),
            ("sigma_color = -0.1", "dense.sigma_color", "(0, 1]"),
        ] {
            let e = with_dense(bad).unwrap_err().to_string();
            assert!(e.contains(key) && e.contains(range), "{bad}: {e}");
        }
    }

    #[test]
    fn inter_epoch_ties_and_outlier_bound_have_defaults_and_name_their_values() {
        let with_align = |line: &str| parse_section("align", line);
        assert_eq!(
            with_align("").unwrap().align.inter_epoch_ties,
            InterEpochTies::Auto
        );
        assert_eq!(
            with_align("inter_epoch_ties = \"stable\"")
                .unwrap()
                .align
                .inter_epoch_ties,
            InterEpochTies::Stable
        );
        assert_eq!(
            with_align("inter_epoch_ties = \"all\"")
                .unwrap()
                .align
                .inter_epoch_ties,
            InterEpochTies::All
        );
        assert_eq!(
            with_align("outlier_bound = \"pooled\"")
                .unwrap()
                .align
                .outlier_bound,
            OutlierBoundConfig::Pooled
        );
        assert!(!with_align("").unwrap().align.join_epoch_ties);
        assert!(
            with_align("join_epoch_ties = true")
                .unwrap()
                .align
                .join_epoch_ties
        );
        let e = with_align("join_epoch_ties = \"yes\"")
            .unwrap_err()
            .to_string();
        assert!(e.contains("join_epoch_ties"), "{e}");
        let e = with_align("outlier_bound = \"camera\"")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("outlier_bound") && e.contains("group") && e.contains("pooled"),
            "{e}"
        );
        let e = with_align("inter_epoch_ties = \"some\"")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("inter_epoch_ties")
                && e.contains("auto")
                && e.contains("stable")
                && e.contains("all"),
            "{e}"
        );
    }
}

/// `[cluster]`: how `timesift run --executor slurm` submits the project's units of work. Every
/// key is optional; the command line's options of the same names override them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClusterConfig {
    /// Slurm partition (`--partition`). Default: the cluster's default partition.
    pub partition: Option<String>,
    /// Slurm account (`--account`). Default: the user's default account.
    pub account: Option<String>,
    /// Time limit per task (`--time`, e.g. `"04:00:00"`). Default: the partition's.
    pub time: Option<String>,
    /// CPUs per task (`--cpus-per-task`), the threads of one unit. Default 4.
    #[serde(default = "default_cpus_per_task")]
    pub cpus_per_task: usize,
    /// Most tasks of one array running at once (`--array=...%N`). Default: no limit.
    pub max_array: Option<usize>,
    /// Further `sbatch` arguments, added to every submission (e.g. `["--qos=long"]`).
    #[serde(default)]
    pub sbatch_args: Vec<String>,
    /// Times a failed task requeues itself before it fails for good. Default 2.
    #[serde(default = "default_retries")]
    pub retries: u32,
    /// Images per task of `features`. Default 40.
    #[serde(default = "default_images_per_task")]
    pub images_per_task: usize,
    /// Pairs per task of `match`. Default 2000.
    #[serde(default = "default_pairs_per_task")]
    pub pairs_per_task: usize,
    /// Reference images per task of each dense pass. Default 8.
    #[serde(default = "default_views_per_task")]
    pub views_per_task: usize,
    /// Ortho cells per task of `ortho`, millions: every epoch's mosaic is made in rows of tiles
    /// shared out among the tasks, then merged by one task per epoch. Default 100 (a task holds
    /// its part in memory: 8 bytes a cell in the plan's `--mem`, its RGBA and the band in the
    /// making).
    #[serde(default = "default_ortho_megapixels_per_task")]
    pub ortho_megapixels_per_task: f64,
}

fn default_cpus_per_task() -> usize {
    4
}
fn default_retries() -> u32 {
    2
}
fn default_images_per_task() -> usize {
    40
}
fn default_pairs_per_task() -> usize {
    2000
}
fn default_views_per_task() -> usize {
    8
}
fn default_ortho_megapixels_per_task() -> f64 {
    100.0
}

impl Default for ClusterConfig {
    fn default() -> Self {
        ClusterConfig {
            partition: None,
            account: None,
            time: None,
            cpus_per_task: default_cpus_per_task(),
            max_array: None,
            sbatch_args: Vec::new(),
            retries: default_retries(),
            images_per_task: default_images_per_task(),
            pairs_per_task: default_pairs_per_task(),
            views_per_task: default_views_per_task(),
            ortho_megapixels_per_task: default_ortho_megapixels_per_task(),
        }
    }
}

impl ClusterConfig {
    /// Checks the counts: each at least 1.
    pub fn validate(&self) -> Result<(), String> {
        for (key, v) in [
            ("cpus_per_task", self.cpus_per_task),
            ("images_per_task", self.images_per_task),
            ("pairs_per_task", self.pairs_per_task),
            ("views_per_task", self.views_per_task),
            ("max_array", self.max_array.unwrap_or(1)),
        ] {
            if v == 0 {
                return Err(format!("[cluster] {key}: expected at least 1, found 0"));
            }
        }
        if !(self.ortho_megapixels_per_task > 0.0 && self.ortho_megapixels_per_task.is_finite()) {
            return Err(format!(
                "[cluster] ortho_megapixels_per_task: expected a positive number, found {}",
                self.ortho_megapixels_per_task
            ));
        }
        Ok(())
    }
}
