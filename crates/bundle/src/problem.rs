//! The problem: camera groups (shared intrinsics with a free/fixed mask), images with poses,
//! points, and reprojection observations with per-observation sigmas.

use nalgebra::{Vector2, Vector3};
use timesift_core::{Camera, CameraModel, Pose};

use crate::BundleError;

/// Intrinsics shared by a group of images, and which of them are adjusted.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraGroup {
    /// The camera model with its current parameters.
    pub camera: Camera,
    /// Per parameter (in `CameraModel::param_names` order): adjusted (`true`) or fixed.
    pub free: Vec<bool>,
}

impl CameraGroup {
    /// A group whose intrinsics are all fixed.
    pub fn fixed(camera: Camera) -> Self {
        let n = camera.num_params();
        CameraGroup {
            camera,
            free: vec![false; n],
        }
    }

    /// A group adjusting the named parameters (others fixed); unknown names are an error.
    pub fn with_free(camera: Camera, names: &[&str]) -> Result<Self, BundleError> {
        let all = camera.param_names();
        let mut free = vec![false; all.len()];
        for name in names {
            let k = all.iter().position(|n| n == name).ok_or_else(|| {
                BundleError::InvalidProblem(format!(
                    "camera model {} has no parameter `{name}` (it has {})",
                    camera.model_name(),
                    all.join(", ")
                ))
            })?;
            free[k] = true;
        }
        Ok(CameraGroup { camera, free })
    }

    /// Number of adjusted intrinsics.
    pub fn num_free(&self) -> usize {
        self.free.iter().filter(|f| **f).count()
    }
}

/// An image: its pose, camera group, and whether the pose is held fixed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BundleImage {
    /// `cam_from_world`.
    pub pose: Pose,
    /// Index into [`BundleProblem::groups`].
    pub group: usize,
    /// Hold the pose fixed.
    pub fixed: bool,
}

/// A 3-D point and whether it is held fixed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BundlePoint {
    /// World position.
    pub position: Vector3<f64>,
    /// Hold the point fixed.
    pub fixed: bool,
}

/// A measurement of a point in an image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    /// Index into [`BundleProblem::images`].
    pub image: usize,
    /// Index into [`BundleProblem::points`].
    pub point: usize,
    /// Measured pixel.
    pub pixel: Vector2<f64>,
    /// Standard deviation, pixels.
    pub sigma_px: f64,
}

/// A prior on a camera centre (GNSS), horizontal and vertical standard deviations apart.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CenterPrior {
    /// Index into [`BundleProblem::images`].
    pub image: usize,
    /// Measured centre (E, N, H), metres.
    pub position: Vector3<f64>,
    /// Horizontal standard deviation, metres.
    pub sigma_xy: f64,
    /// Vertical standard deviation, metres.
    pub sigma_z: f64,
    /// The offset (index into [`BundleProblem::prior_offsets`]) this measurement carries, if
    /// any: the measurement is the true centre plus the offset, so the residual is
    /// `C − (position − offset)`.
    pub offset: Option<usize>,
}

/// An unknown constant offset shared by several camera-centre priors: the bias of one GNSS
/// receiver over one flight (metres, the same for every image of it), which consumer receivers
/// carry at the metre level while their flight-internal noise is centimetres. Estimated with a
/// zero-mean prior of the stated σ (as OpenSfM's GPS-bias compensation and Metashape's per-group
/// location offsets do), or held fixed (e.g. at zero for a flight whose offset is the datum).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PriorOffset {
    /// Current estimate (E, N, H), metres.
    pub value: Vector3<f64>,
    /// Horizontal standard deviation of the zero-mean prior, metres.
    pub sigma_xy: f64,
    /// Vertical standard deviation of the zero-mean prior, metres.
    pub sigma_z: f64,
    /// Hold the offset at `value`.
    pub fixed: bool,
}

/// A prior on a point's object coordinates (a ground control point measured by markers).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointPrior {
    /// Index into [`BundleProblem::points`].
    pub point: usize,
    /// Surveyed coordinates (E, N, H), metres.
    pub position: Vector3<f64>,
    /// Horizontal standard deviation, metres.
    pub sigma_xy: f64,
    /// Vertical standard deviation, metres.
    pub sigma_z: f64,
    /// Slope (dz/dx, dz/dy) of the surface the height lies on: the vertical residual is the
    /// point's height above the surface's tangent plane through `position`, so that a point
    /// moved sideways on a slope is not pulled up or down (a height from a reference DEM). Zero
    /// for a surveyed point.
    pub slope: [f64; 2],
}

impl PointPrior {
    /// The residual of a point at `at`, scaled by the σs, and its Jacobian with respect to the
    /// point (constant: the residual is linear in it).
    pub fn residual(&self, at: &Vector3<f64>) -> (Vector3<f64>, nalgebra::Matrix3<f64>) {
        let d = at - self.position;
        let (sx, sz) = (1.0 / self.sigma_xy, 1.0 / self.sigma_z);
        let [gx, gy] = self.slope;
        let r = Vector3::new(sx * d.x, sx * d.y, sz * (d.z - gx * d.x - gy * d.y));
        let j = nalgebra::Matrix3::new(sx, 0.0, 0.0, 0.0, sx, 0.0, -gx * sz, -gy * sz, sz);
        (r, j)
    }

    /// The residual unscaled (metres): east, north, and the height above the tangent plane.
    pub fn miss(&self, at: &Vector3<f64>) -> Vector3<f64> {
        let d = at - self.position;
        Vector3::new(d.x, d.y, d.z - self.slope[0] * d.x - self.slope[1] * d.y)
    }
}

/// A scale bar: the measured distance between two points (markers), with its accuracy.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScaleBar {
    /// Index into [`BundleProblem::points`] of one end.
    pub a: usize,
    /// The other end.
    pub b: usize,
    /// Measured distance, metres.
    pub length: f64,
    /// Standard deviation of the distance, metres.
    pub sigma: f64,
}

/// A bundle-adjustment problem.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BundleProblem {
    /// Camera groups.
    pub groups: Vec<CameraGroup>,
    /// Images.
    pub images: Vec<BundleImage>,
    /// Points.
    pub points: Vec<BundlePoint>,
    /// Reprojection observations.
    pub observations: Vec<Observation>,
    /// Camera-centre priors (GNSS).
    pub center_priors: Vec<CenterPrior>,
    /// Offsets shared by camera-centre priors (GNSS bias per flight).
    pub prior_offsets: Vec<PriorOffset>,
    /// Object-coordinate priors of control points.
    pub point_priors: Vec<PointPrior>,
    /// Distances between pairs of points.
    pub scale_bars: Vec<ScaleBar>,
}

impl BundleProblem {
    /// Checks indices, masks, sigmas and finiteness.
    pub fn validate(&self) -> Result<(), BundleError> {
        self.validate_groups_and_images()?;
        self.validate_points_and_observations()?;
        self.validate_center_priors()?;
        self.validate_offsets_and_point_priors()?;
        self.validate_scale_bars()
    }

    /// Checks the camera groups' masks, the images' group indices and that poses are finite.
    fn validate_groups_and_images(&self) -> Result<(), BundleError> {
        for (i, g) in self.groups.iter().enumerate() {
            if g.free.len() != g.camera.num_params() {
                return Err(BundleError::InvalidProblem(format!(
                    "camera group {i}: mask has {} entries for {} parameters",
                    g.free.len(),
                    g.camera.num_params()
                )));
            }
        }
        for (i, im) in self.images.iter().enumerate() {
            if im.group >= self.groups.len() {
                return Err(BundleError::InvalidProblem(format!(
                    "image {i} refers to camera group {} of {}",
                    im.group,
                    self.groups.len()
                )));
            }
            if !im
                .pose
                .translation
                .iter()
                .chain(im.pose.rotation.coords.iter())
                .all(|v| v.is_finite())
            {
                return Err(BundleError::NonFinite("pose"));
            }
        }
        Ok(())
    }

    /// Checks that points are finite, and the observations' indices, sigmas and pixels.
    fn validate_points_and_observations(&self) -> Result<(), BundleError> {
        if !self
            .points
            .iter()
            .all(|p| p.position.iter().all(|v| v.is_finite()))
        {
            return Err(BundleError::NonFinite("point"));
        }
        for (k, o) in self.observations.iter().enumerate() {
            if o.image >= self.images.len() || o.point >= self.points.len() {
                return Err(BundleError::InvalidProblem(format!(
                    "observation {k} refers to image {} / point {} out of range",
                    o.image, o.point
                )));
            }
            if !(o.sigma_px > 0.0) || !o.pixel.iter().all(|v| v.is_finite()) {
                return Err(BundleError::InvalidProblem(format!(
                    "observation {k} has a non-positive sigma or non-finite pixel"
                )));
            }
        }
        Ok(())
    }

    /// Checks the centre priors' images, sigmas, positions and offsets.
    fn validate_center_priors(&self) -> Result<(), BundleError> {
        for (k, c) in self.center_priors.iter().enumerate() {
            if c.image >= self.images.len()
                || !(c.sigma_xy > 0.0 && c.sigma_z > 0.0)
                || !c.position.iter().all(|v| v.is_finite())
            {
                return Err(BundleError::InvalidProblem(format!(
                    "centre prior {k}: image {} out of range, non-positive sigma or non-finite position",
                    c.image
                )));
            }
            if c.offset.is_some_and(|o| o >= self.prior_offsets.len()) {
                return Err(BundleError::InvalidProblem(format!(
                    "centre prior {k}: offset {:?} of {}",
                    c.offset,
                    self.prior_offsets.len()
                )));
            }
        }
        Ok(())
    }

    /// Checks the prior offsets' sigmas and values, then the point priors' points, sigmas and
    /// positions.
    fn validate_offsets_and_point_priors(&self) -> Result<(), BundleError> {
        for (k, o) in self.prior_offsets.iter().enumerate() {
            let valid =
                o.sigma_xy > 0.0 && o.sigma_z > 0.0 && o.value.iter().all(|v| v.is_finite());
            if !valid {
                return Err(BundleError::InvalidProblem(format!(
                    "prior offset {k}: non-positive sigma or non-finite value"
                )));
            }
        }
        for (k, c) in self.point_priors.iter().enumerate() {
            let valid = c.point < self.points.len()
                && c.sigma_xy > 0.0
                && c.sigma_z > 0.0
                && c.position.iter().chain(&c.slope).all(|v| v.is_finite());
            if !valid {
                return Err(BundleError::InvalidProblem(format!(
                    "point prior {k}: point {} out of range, non-positive sigma or non-finite position or slope",
                    c.point
                )));
            }
        }
        Ok(())
    }

    /// Checks that each scale bar joins two distinct points with a finite positive length and σ.
    fn validate_scale_bars(&self) -> Result<(), BundleError> {
        for (k, bar) in self.scale_bars.iter().enumerate() {
            if bar.a >= self.points.len() || bar.b >= self.points.len() || bar.a == bar.b {
                return Err(BundleError::InvalidProblem(format!(
                    "scale bar {k}: points {} and {} must be two distinct points of {}",
                    bar.a,
                    bar.b,
                    self.points.len()
                )));
            }
            if !(bar.length > 0.0
                && bar.length.is_finite()
                && bar.sigma > 0.0
                && bar.sigma.is_finite())
            {
                return Err(BundleError::InvalidProblem(format!(
                    "scale bar {k}: length {} and sigma {} must be finite and positive",
                    bar.length, bar.sigma
                )));
            }
        }
        Ok(())
    }
}
