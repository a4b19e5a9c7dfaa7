//! The JSON reports timesift writes, as typed structs shared by their writers, their readers
//! (`eval`, `timesift demo`, the benches, tests) and their documentation: `out/report.json` of
//! the align stage, `work/matches/summary.json` of the match stage, `out/dense.json` of the
//! dense stage, `out/grid.json` (the project's lattice) and `out/raster.json` of the dem and
//! ortho stages. Field names are the JSON keys.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::ProjectError;

/// `out/report.json`: the orientation, per block and per epoch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AlignReport {
    /// Strategy (`[align] method`).
    pub method: timesift_align::Method,
    /// What fixed the datum (`Local`, `Gnss…`, `ControlPoints…`).
    pub datum: String,
    /// Images in the project.
    pub images_given: usize,
    /// Images oriented.
    pub images_oriented: usize,
    /// RMS reprojection error of the block, pixels.
    pub rms_reprojection_px: Option<f64>,
    /// Tie points.
    pub tie_points: usize,
    /// The structure from motion that oriented the images: `incremental` or `global`
    /// (`[align] mapper`; `global` falls back to `incremental` without GNSS priors).
    #[serde(default)]
    pub mapper: Option<String>,
    /// Inter-epoch tie points split by epoch because their surface moved.
    pub inter_epoch_ties_split_as_moved: usize,
    /// Inter-epoch tie points split by epoch because they lie off the stable areas, or (without
    /// stable areas, `[align] inter_epoch_ties = "auto"`) on ground the block's own ties show
    /// changed.
    #[serde(default)]
    pub inter_epoch_ties_split_off_stable: usize,
    /// Tie points of two epochs joined into inter-epoch ties by descriptor once the first block
    /// put them together (`[align] join_epoch_ties`).
    #[serde(default)]
    pub inter_epoch_ties_joined: usize,
    /// Inter-epoch ties found near where the first block projects a point into another
    /// epoch's images (`[align] guided_epoch_ties`): keypoints added and tracks joined.
    #[serde(default)]
    pub inter_epoch_ties_guided: usize,
    /// Regions found changed from the block's own inter-epoch ties (`[align] inter_epoch_ties =
    /// "auto"` without stable areas); 0 otherwise.
    #[serde(default)]
    pub changed_regions: usize,
    /// Height observations from the reference epoch's surface on the later epochs' tie points
    /// (`[align] surface_ties`), or from the reference DEM on every epoch's; 0 without them.
    #[serde(default)]
    pub surface_heights: usize,
    /// `[align] reference_dem` as given, when the epochs were held to it: each epoch's
    /// `surface_fit` is then against it (the reference epoch's too).
    #[serde(default)]
    pub reference_dem: Option<String>,
    /// Observations beyond this reprojection error were outliers, pixels (pooled over the
    /// block; each camera group's own bound is in `group_noise`).
    pub observation_bound_px: Option<f64>,
    /// Per camera group (as `cameras`): the σ of its own reprojection errors and its own
    /// outlier bound, so a noisier group (scanned film) is judged by its own noise.
    #[serde(default)]
    pub group_noise: Vec<GroupNoise>,
    /// Reconstructed components that could not be placed.
    pub components_dropped: usize,
    /// GNSS priors rejected as outliers.
    pub gnss_priors_rejected: usize,
    /// Whether a known focal length was held.
    pub focal_length_held: Vec<bool>,
    /// Intrinsics per camera group, by parameter name.
    pub cameras: Vec<BTreeMap<String, f64>>,
    /// Wall time of the stage, seconds.
    pub seconds: f64,
    /// Per epoch, by name.
    pub epochs: BTreeMap<String, EpochOrientation>,
    /// Camera terms `out/colmap/` could not hold and left out (COLMAP has no skew `b2` nor
    /// radial `k4`: a film camera's `b2` freed by `[align] self_calibration`); `cameras.json`
    /// holds them. Empty: the COLMAP copy is exact.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub colmap_terms_dropped: Vec<String>,
    /// Per pair of epochs, the tie points observed in both and how they spread.
    #[serde(default)]
    pub epoch_pairs: Vec<EpochPairTies>,
    /// The epochs a joint block (`timesift`, `msfm`) did not tie to the reference epoch: no
    /// chain of epoch pairs sharing [`MIN_CO_REGISTERING_TIES`] tie points leads from them to
    /// it. Their orientation rests on their own GNSS priors and control points alone, so their
    /// DEMs stack with the others' only as well as that control allows.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub not_co_registered: Vec<String>,
    /// Control points left out of the adjustment: where the other priors and control points
    /// place the block, their markers intersect far from their surveyed coordinates. Their
    /// residuals (under each epoch's `control_points`) say by how much.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub control_points_rejected: Vec<String>,
}

/// The tie points two epochs must share for the block to hold one to the other: fewer cannot
/// fix an epoch's seven degrees of freedom robustly against a few wrong matches.
pub const MIN_CO_REGISTERING_TIES: usize = 20;

/// The tie points two epochs share and their spread against every tie point's, along the
/// block's principal axes: inter-epoch ties bunched along a corridor's axis leave a roll about
/// it free.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpochPairTies {
    /// The two epochs.
    pub epochs: [String; 2],
    /// Tie points observed in both.
    pub ties: usize,
    /// Their standard deviation across the block (its minor horizontal axis), metres.
    pub across_std_m: Option<f64>,
    /// Their standard deviation along the block (its major horizontal axis), metres.
    pub along_std_m: Option<f64>,
    /// Every tie point's standard deviation across the block, metres.
    pub all_across_std_m: f64,
    /// Every tie point's standard deviation along the block, metres.
    pub all_along_std_m: f64,
    /// The standard deviation across the block of the tie points observed in both together
    /// with the points of either epoch held to the reference epoch's surface (surface ties),
    /// metres: across how much of the block the pair is tied. `None` where neither is held.
    #[serde(default)]
    pub held_across_std_m: Option<f64>,
    /// The standard deviation across the block of every tie point on the stable areas
    /// (`stable.csv`), metres: the ground the pair can be tied on. `None` without stable areas.
    #[serde(default)]
    pub stable_across_std_m: Option<f64>,
    /// The tilt of the second epoch's surface against the first's (the DoD's tilt) that the
    /// block allows, from its covariance: what the inter-epoch ties, GNSS and control hold.
    #[serde(default)]
    pub dod_tilt: Option<DatumTiltReport>,
}

/// One epoch of [`AlignReport`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpochOrientation {
    /// Images of the epoch.
    pub images_given: usize,
    /// Images oriented.
    pub images_oriented: usize,
    /// RMS reprojection error of the epoch's observations, pixels.
    pub rms_reprojection_px: Option<f64>,
    /// Observations of the epoch's images.
    pub observations: usize,
    /// Tie points observed in the epoch.
    pub tie_points: usize,
    /// Tie points observed in the epoch and another.
    pub inter_epoch_tie_points: usize,
    /// Control-point residuals from this epoch's markers.
    pub control_points: PointResiduals,
    /// Check-point residuals from this epoch's markers.
    pub check_points: PointResiduals,
    /// The GNSS offset estimated for the epoch (`[gnss] offsets = "epoch"`).
    #[serde(default)]
    pub gnss_offset: Option<GnssOffset>,
    /// How loosely the control the epoch rests on fixes the tilt of its datum.
    #[serde(default)]
    pub datum_tilt: Option<DatumTiltReport>,
    /// The tilt of the epoch's surface against the world that the whole block allows, from its
    /// covariance (`timesift_bundle::rigid`): unlike `datum_tilt`, it follows how the epoch
    /// hangs on its inter-epoch ties, and how the tie points may bend it as a whole.
    #[serde(default)]
    pub block_tilt: Option<DatumTiltReport>,
    /// The epoch's own tie points on stable ground against the reference epoch's surface in
    /// the final block (not for the reference epoch), or against the reference DEM when
    /// `reference_dem` is set: what separates their surfaces, term by term, each with its σ.
    #[serde(default)]
    pub surface_fit: Option<SurfaceFitReport>,
}

/// A later epoch's tie points against the reference epoch's surface (the local plane of the
/// reference epoch's tie points around each): their height misses decomposed by least squares
/// into an offset, a tilt (two slopes), a dome (a term in the squared distance from their
/// centroid) and a height scale (a term in the height above their mean), each with its σ from
/// the scatter about the fit. A term beyond 3 σ is a systematic difference the epochs' DEMs and
/// DoDs will show over stable ground; within, the block holds the epochs together to that σ.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SurfaceFitReport {
    /// Points compared (on stable ground where given, where the reference surface is known).
    pub points_compared: usize,
    /// Points kept (the others miss the fitted offset, tilt and dome by more than 2.5 σ, or lie
    /// where their neighbourhood misses it as a whole: ground that changed, wrong points).
    pub points_kept: usize,
    /// Of the epoch's points, how many the final adjustment held to the surface by height
    /// observations (others than those compared here, which are never held; a point of several
    /// epochs held to a reference DEM counts for the first). 0: the epoch sits where its ties
    /// to the others put it (too few points, or nothing to correct).
    #[serde(default)]
    pub points_held: usize,
    /// One point's miss about the fit, metres (robust σ).
    pub sigma_m: f64,
    /// Offset at the points' centroid, metres.
    pub offset_m: Term,
    /// Slope of the misses eastwards, mm/m.
    pub slope_east_mm_per_m: Term,
    /// Slope of the misses northwards, mm/m.
    pub slope_north_mm_per_m: Term,
    /// Magnitude of the tilt, mm/m.
    pub tilt_mm_per_m: Term,
    /// The dome's rise at 100 m from the centroid, mm.
    pub dome_mm_at_100m: Option<Term>,
    /// Height scale: mm of miss per metre of the reference surface's height above its own
    /// best plane; `None` over ground too flat to tell it from a tilt.
    pub height_scale_mm_per_m: Option<Term>,
}

/// An estimate with its standard deviation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Term {
    /// Value.
    pub value: f64,
    /// Standard deviation.
    pub sigma: f64,
}

impl Term {
    /// Beyond 3 σ.
    pub fn significant(&self) -> bool {
        self.value.abs() > 3.0 * self.sigma
    }
}

/// The standard deviation of a datum's tilt that its control allows, predicted from the
/// control alone (control points' survey σ, GNSS heights with their flight's offset estimated,
/// the block taken as rigid: a lower bound). Over a DoD `w` metres wide, a tilt of σ mm/m is
/// ±σ·w/1000 m of false change at its edges.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DatumTiltReport {
    /// About the loosest horizontal axis, mm per m.
    pub sigma_max_mm_per_m: f64,
    /// About the firmest, mm per m.
    pub sigma_min_mm_per_m: f64,
    /// Direction of the loosest tilt's gradient, degrees counter-clockwise from east.
    pub loose_azimuth_deg: f64,
    /// The datum's height σ at the weighted centre of what fixes it, metres, where that fixes
    /// one (the prediction from the control points, GNSS priors and reference DEM heights
    /// alone, `datum_tilt`): how far every DEM of the block may sit up or down together. With a
    /// reference DEM it is relative to that DEM: the DEM's own vertical error is not in it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma_height_m: Option<f64>,
}

/// An epoch's estimated GNSS offset: its receiver's positions minus the true camera centres,
/// common to the flight, metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GnssOffset {
    /// East, north, up.
    pub offset: [f64; 3],
    /// Standard deviations (east, north, up), when the adjustment's covariance was available.
    pub std: Option<[f64; 3]>,
    /// Priors that carried it.
    pub priors: usize,
    /// Largest |correlation| of the up component with a free focal length (above
    /// [`FOCAL_CORRELATION_WARNING`] the report says the two cannot be told apart).
    #[serde(default)]
    pub focal_correlation: Option<f64>,
    /// The scatter of the flight's positions about the offset (horizontal per axis,
    /// vertical), metres, estimated from its priors.
    #[serde(default)]
    pub within_flight_sigma_m: Option<[f64; 2]>,
    /// Whether the final adjustment weighed the flight's priors by that scatter (where below
    /// the stated accuracy): by default the flights of the images control points are marked
    /// in, or every flight when no control point is marked (`[gnss] weigh_by_scatter`).
    #[serde(default)]
    pub scatter_weighs_priors: bool,
}

/// The reprojection noise of one camera group, pixels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GroupNoise {
    /// σ per image axis, robustly from the median error of the group's observations.
    pub sigma_px: Option<f64>,
    /// Observations of the group beyond this error were outliers.
    pub bound_px: Option<f64>,
}

/// Correlation of a vertical GNSS offset with a focal length above which the report warns: the
/// block cannot separate them (nadir images over flat ground) and the offset's prior decides.
pub const FOCAL_CORRELATION_WARNING: f64 = 0.9;

/// Residuals of ground points (intersected from markers − surveyed), metres.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PointResiduals {
    /// Per point.
    pub points: Vec<PointResidual>,
    /// RMSE over the measured points, `None` when none was measured.
    pub rmse: Option<Rmse>,
    /// The RMSE that the markers' own accuracy alone gives over the same points (the RMS of
    /// their `markers_sigma`): what `rmse` would be, in expectation, with a perfect orientation.
    /// A measured RMSE near it says the check points cannot tell this orientation from a better
    /// one. `None` in reports written before it existed.
    #[serde(default)]
    pub markers_rmse: Option<Rmse>,
}

/// One ground point's residual.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PointResidual {
    /// Point name.
    pub name: String,
    /// Images whose markers measured it.
    pub images: usize,
    /// East residual, `None` when it could not be intersected.
    #[serde(rename = "dE")]
    pub de: Option<f64>,
    /// North residual.
    #[serde(rename = "dN")]
    pub dn: Option<f64>,
    /// Height residual.
    #[serde(rename = "dH")]
    pub dh: Option<f64>,
    /// Standard deviations (E, N, H) of the intersected position from the markers' accuracy
    /// alone, through the adjusted cameras, metres.
    #[serde(default)]
    pub markers_sigma: Option<[f64; 3]>,
}

impl PointResidual {
    /// The residual vector, when measured.
    pub fn vector(&self) -> Option<[f64; 3]> {
        Some([self.de?, self.dn?, self.dh?])
    }
}

/// RMSE per component.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Rmse {
    /// East.
    #[serde(rename = "dE")]
    pub de: f64,
    /// North.
    #[serde(rename = "dN")]
    pub dn: f64,
    /// Height.
    #[serde(rename = "dH")]
    pub dh: f64,
    /// Points.
    pub n: usize,
}

/// `work/matches/summary.json`: what the match stage verified.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MatchSummary {
    /// Pairs the policy proposed.
    pub candidate_pairs: usize,
    /// Pairs matched (after preselection).
    pub pairs: usize,
    /// Pairs with verified matches.
    pub verified_pairs: usize,
    /// Verified pairs per epoch pair (`<a>__<b>`).
    pub verified_pairs_per_epoch_pair: BTreeMap<String, usize>,
    /// Tracks built.
    pub tracks: usize,
    /// Matches dropped as conflicting.
    pub conflicting_matches: usize,
    /// Tracks per length.
    pub track_lengths: BTreeMap<usize, usize>,
}

impl std::fmt::Display for MatchSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} of {} pairs verified, {} tracks",
            self.verified_pairs, self.pairs, self.tracks
        )
    }
}

/// `out/dense.json`: what the dense stage did, per epoch.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct DenseReport {
    /// Per epoch, by name.
    pub epochs: BTreeMap<String, EpochDense>,
}

/// One epoch of [`DenseReport`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpochDense {
    /// Oriented images of the epoch.
    pub images: usize,
    /// Images that had source views (and so a depth map).
    pub images_with_sources: usize,
    /// Level (1 full resolution, 2 half, …).
    pub level: u32,
    /// PatchMatch passes (coarse to fine).
    pub passes: usize,
    /// With `[dense] refine`, the share of the final maps' depths matched again at twice the
    /// resolution (the rest keep the level's planes); none without refinement.
    #[serde(default)]
    pub refined_share: Option<f64>,
    /// Depth maps computed in this run (the rest came from the cache).
    pub depth_maps_computed: usize,
    /// Fused points.
    pub points: usize,
    /// Mean images per fused point.
    pub mean_images_per_point: f64,
    /// Wall time of the epoch in this run, seconds.
    pub seconds: f64,
    /// Where that time went (wall seconds per phase of this run; maps taken from the cache
    /// cost nothing).
    #[serde(default)]
    pub phase_seconds: DensePhaseSeconds,
}

/// Wall seconds of the phases of one epoch's dense matching: what to look at first when the
/// stage is slow.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct DensePhaseSeconds {
    /// Decoding and undistorting images to the working resolution.
    pub images: f64,
    /// PatchMatch passes from random planes at the coarsest scale.
    pub photometric: f64,
    /// PatchMatch passes from the coarser scale's planes (ACMM's detail restorer).
    pub hierarchy: f64,
    /// PatchMatch passes with the geometric-consistency term.
    pub geometric: f64,
    /// Refinement passes at twice the level's resolution.
    pub refine: f64,
    /// Reading and writing depth maps (`work/dense/`).
    pub map_files: f64,
    /// Filtering each final map against its neighbours.
    pub filter: f64,
    /// Fusing the filtered maps into points.
    pub fusion: f64,
    /// Writing the LAZ cloud.
    pub cloud_file: f64,
}

impl std::ops::AddAssign<&DensePhaseSeconds> for DensePhaseSeconds {
    /// Phase by phase (several epochs' times together).
    fn add_assign(&mut self, other: &DensePhaseSeconds) {
        self.images += other.images;
        self.photometric += other.photometric;
        self.hierarchy += other.hierarchy;
        self.geometric += other.geometric;
        self.refine += other.refine;
        self.map_files += other.map_files;
        self.filter += other.filter;
        self.fusion += other.fusion;
        self.cloud_file += other.cloud_file;
    }
}

/// `out/fiducials.json`: the fiducial marks and interior orientation of every scan.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct FiducialsReport {
    /// Every scan of a film camera, in project order.
    pub images: Vec<ScanReport>,
}

/// One scan of [`FiducialsReport`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScanReport {
    /// Image path relative to the project.
    pub image: String,
    /// Its camera group.
    pub camera: String,
    /// Its marks, in the certificate's order.
    pub marks: Vec<MarkReport>,
    /// `affine`, `projective` or `similarity`; empty when the scan could not be oriented.
    pub model: String,
    /// Frame pixels → scan pixels (homogeneous, row-major); `None` when the scan could not be
    /// oriented.
    pub scan_from_frame: Option<[[f64; 3]; 3]>,
    /// RMS of the residuals of the marks used, scan pixels.
    pub rms_px: Option<f64>,
    /// Scan scale against the certificate's pixel size (larger, smaller).
    pub scales: Option<[f64; 2]>,
    /// Rotation of the frame in the scan, degrees.
    pub rotation_deg: Option<f64>,
    /// Warnings, one line each, naming the mark.
    pub warnings: Vec<String>,
    /// Why the scan has no interior orientation.
    pub error: Option<String>,
}

/// One mark of [`ScanReport`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MarkReport {
    /// The certificate's name of the mark.
    pub mark: String,
    /// Measured position, scan pixels (`None`: not found).
    pub uv: Option<[f64; 2]>,
    /// Correlation with the template (1 for a mark given by hand).
    pub correlation: f64,
    /// Distance from the interior orientation, scan pixels.
    pub residual_px: Option<f64>,
    /// `measured`, `given`, `not found` or `rejected`.
    pub status: String,
}

/// Writes a report as pretty JSON, atomically.
pub fn write_json<T: Serialize>(path: &Path, report: &T) -> Result<(), ProjectError> {
    let text = serde_json::to_string_pretty(report).map_err(|e| ProjectError::Path {
        path: path.to_path_buf(),
        message: format!("cannot serialise: {e}"),
    })?;
    timesift_io::fsutil::write_bytes_atomically(path, text.as_bytes())?;
    Ok(())
}

/// Reads a report written by [`write_json`]; the error names the file and what is wrong.
pub fn read_json<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<T, ProjectError> {
    let text = timesift_io::fsutil::read_text(path)?;
    serde_json::from_str(&text).map_err(|e| ProjectError::Path {
        path: path.to_path_buf(),
        message: format!("not the expected report: {e}"),
    })
}

/// The key of a sealed record's checksum ([`write_sealed_json`]).
const SEAL_KEY: &str = "checksum";

/// FNV-1a (64 bit) of a record's compact JSON text without its seal.
fn seal_of(record: &serde_json::Value) -> String {
    let mut hash = timesift_io::fingerprint::Fnv1a::new();
    hash.write(record.to_string().as_bytes());
    format!("fnv1a64:{}", hash.hex())
}

/// Writes a record of cached work (under `work/`: what a result was made from, or a result
/// reused by later runs) as [`write_json`] does, with a `checksum` key over the rest: a digit
/// changed by a damaged disk still parses, and [`read_sealed_json`] refuses it, so the work is
/// redone rather than trusted. The record must serialise to a JSON object.
pub fn write_sealed_json<T: Serialize>(path: &Path, record: &T) -> Result<(), ProjectError> {
    let not_object = || ProjectError::Path {
        path: path.to_path_buf(),
        message: "a sealed record must be a JSON object".into(),
    };
    let mut value = serde_json::to_value(record).map_err(|e| ProjectError::Path {
        path: path.to_path_buf(),
        message: format!("cannot serialise: {e}"),
    })?;
    let seal = seal_of(&value);
    let object = value.as_object_mut().ok_or_else(not_object)?;
    // A field of the record's own by the seal's name would be overwritten and fail every read.
    if object.contains_key(SEAL_KEY) {
        return Err(ProjectError::Path {
            path: path.to_path_buf(),
            message: format!("a sealed record cannot have a field named \"{SEAL_KEY}\""),
        });
    }
    object.insert(SEAL_KEY.into(), seal.into());
    write_json(path, &value)
}

/// Reads a record written by [`write_sealed_json`]; a missing or wrong checksum is an error
/// naming the file (the caller recomputes what it records).
pub fn read_sealed_json<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<T, ProjectError> {
    let error = |message: String| ProjectError::Path {
        path: path.to_path_buf(),
        message,
    };
    let mut value: serde_json::Value = read_json(path)?;
    let recorded = value
        .as_object_mut()
        .and_then(|m| m.remove(SEAL_KEY))
        .and_then(|v| v.as_str().map(str::to_string))
        .ok_or_else(|| error("no checksum: not a record of this version, or cut short".into()))?;
    let found = seal_of(&value);
    if found != recorded {
        return Err(error(format!(
            "checksum mismatch: the record hashes to {found}, it recorded {recorded} (changed \
             or damaged after it was written)"
        )));
    }
    serde_json::from_value(value).map_err(|e| error(format!("not the expected record: {e}")))
}

/// `out/grid.json`: the one raster lattice of the project, used by every epoch's DEM and ortho.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GridFile {
    /// CRS of the coordinates (`"EPSG:<code>"` or `"local"`).
    pub crs: String,
    /// (x, y) of the north-west corner of the north-west cell.
    pub origin: [f64; 2],
    /// DEM cell, metres.
    pub dem_cell: f64,
    /// Ortho cell, metres (the DEM cell divided by `ortho_factor`).
    pub ortho_cell: f64,
    /// Ortho cells per DEM cell along each axis.
    pub ortho_factor: usize,
    /// DEM lattice size (columns, rows).
    pub size: [usize; 2],
    /// Ortho lattice size (columns, rows).
    pub ortho_size: [usize; 2],
    /// Median ground sample distance of each epoch's images, metres.
    pub epoch_gsd: BTreeMap<String, f64>,
    /// What the lattice was derived from (`[raster]` lattice keys and the epochs); a resumed
    /// run keeps the lattice while these are unchanged.
    pub made_from: serde_json::Value,
}

/// `out/raster.json`: the dem and ortho stages per epoch.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct RasterReport {
    /// Per epoch, by name.
    pub epochs: BTreeMap<String, EpochRaster>,
}

/// One epoch of [`RasterReport`].
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct EpochRaster {
    /// Points of the dense cloud.
    pub cloud_points: usize,
    /// DEM cells with a height, measured or filled.
    pub dem_cells: usize,
    /// DEM cells filled by interpolation.
    pub dem_cells_filled: usize,
    /// Time to grid the DEM, seconds.
    pub dem_seconds: f64,
    /// Fraction of the DEM's cells with a height whose ortho cells are painted.
    pub ortho_painted_fraction: Option<f64>,
    /// Mean absolute colour step (0–255) across ortho seams.
    pub seam_jump: Option<f64>,
    /// The same between neighbouring ortho cells away from seams (texture contrast).
    pub interior_jump: Option<f64>,
    /// Time to mosaic the ortho, seconds.
    pub ortho_seconds: Option<f64>,
}

/// `work/run.json`: each stage's latest run, for the report's time table.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct RunLog {
    /// timesift version that ran the stages.
    pub version: String,
    /// Per stage name.
    pub stages: BTreeMap<String, StageRun>,
}

/// One stage of [`RunLog`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageRun {
    /// Wall time of its latest run, seconds (short when it found its work up to date).
    pub seconds: f64,
    /// Its one-line summary.
    pub summary: String,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sealed_record_reads_back_and_a_changed_digit_or_a_field_named_like_the_seal_is_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("r.json");
        let record = serde_json::json!({"made_from": "a", "seconds": 1.25});
        write_sealed_json(&path, &record).expect("write");
        let back: serde_json::Value = read_sealed_json(&path).expect("read");
        assert_eq!(back["seconds"], 1.25);
        let text = std::fs::read_to_string(&path).expect("text");
        std::fs::write(&path, text.replace("1.25", "1.35")).expect("write");
        let e = read_sealed_json::<serde_json::Value>(&path).expect_err("changed digit");
        assert!(e.to_string().contains("r.json"), "{e}");
        let e = write_sealed_json(&path, &serde_json::json!({"checksum": "0"}))
            .expect_err("a field named checksum");
        assert!(e.to_string().contains("checksum"), "{e}");
    }
}
