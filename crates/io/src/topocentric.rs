//! The frame other tools expect a georeferenced block in: topocentric East-North-Up around a
//! reference latitude, longitude and ellipsoidal height (OpenSfM's `reference_lla`; Metashape's
//! chunk frame, placed in geocentric coordinates by one rotation and translation).
//!
//! Why not hand over the projected coordinates: a projected CRS is not a Cartesian frame — its
//! grid north turns away from true north (meridian convergence, about a degree at the edge of a
//! UTM zone) and its horizontal scale differs from 1 — so a block moved into a tool that treats
//! coordinates as Cartesian ENU would be rotated. Here every point is converted exactly (grid →
//! WGS84 → geocentric → ENU), and every camera keeps its centre exactly and takes the rotation of
//! the local frame at its centre (the polar factor of the conversion's Jacobian), which is what
//! the bundle adjustment's Euclidean treatment of the grid meant. Heights are taken as ellipsoidal.

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use timesift_core::Pose;

use crate::IoError;
use crate::coords::{Crs, Projector};

/// WGS84 semi-major axis, m.
const A: f64 = 6_378_137.0;
/// WGS84 flattening.
const F: f64 = 1.0 / 298.257_223_563;

/// Geocentric (ECEF) coordinates of a WGS84 latitude, longitude (degrees) and ellipsoidal height.
pub fn ecef_from_geodetic(latitude: f64, longitude: f64, height: f64) -> Vector3<f64> {
    let (lat, lon) = (latitude.to_radians(), longitude.to_radians());
    let e2 = F * (2.0 - F);
    let n = A / (1.0 - e2 * lat.sin().powi(2)).sqrt();
    Vector3::new(
        (n + height) * lat.cos() * lon.cos(),
        (n + height) * lat.cos() * lon.sin(),
        (n * (1.0 - e2) + height) * lat.sin(),
    )
}

/// The rotation from geocentric axes to the East-North-Up axes at a latitude and longitude.
pub fn enu_from_ecef(latitude: f64, longitude: f64) -> Matrix3<f64> {
    let (lat, lon) = (latitude.to_radians(), longitude.to_radians());
    let (sl, cl, sp, cp) = (lon.sin(), lon.cos(), lat.sin(), lat.cos());
    Matrix3::new(-sl, cl, 0.0, -sp * cl, -sp * sl, cp, cp * cl, cp * sl, sp)
}

/// The map from a project's world frame to the frame an export is written in.
pub enum ExportFrame {
    /// A local world frame: exported as it is.
    Local,
    /// A projected CRS: exported in topocentric ENU around `reference`.
    Topocentric {
        /// Grid ↔ WGS84 (boxed: it is large, and there is one frame per export).
        projector: Box<Projector>,
        /// Latitude, longitude (degrees) and ellipsoidal height of the origin.
        reference: [f64; 3],
        /// Geocentric position of the origin.
        ecef_origin: Vector3<f64>,
        /// ENU axes at the origin from geocentric axes.
        enu_from_ecef: Matrix3<f64>,
    },
}

impl ExportFrame {
    /// The frame for a world CRS, centred on `centre` (world coordinates, e.g. the cameras'
    /// mean centre).
    pub fn new(crs: Crs, centre: Vector3<f64>) -> Result<ExportFrame, IoError> {
        if crs == Crs::Local {
            return Ok(ExportFrame::Local);
        }
        let projector = Projector::new(crs)?;
        let (lat, lon) = projector.unproject(centre.x, centre.y)?;
        Ok(ExportFrame::Topocentric {
            projector: Box::new(projector),
            reference: [lat, lon, centre.z],
            ecef_origin: ecef_from_geodetic(lat, lon, centre.z),
            enu_from_ecef: enu_from_ecef(lat, lon),
        })
    }

    /// Latitude, longitude and height of the origin (`None` for a local frame).
    pub fn reference(&self) -> Option<[f64; 3]> {
        match self {
            ExportFrame::Local => None,
            ExportFrame::Topocentric { reference, .. } => Some(*reference),
        }
    }

    /// The origin's geocentric position and the rotation from the frame's axes to geocentric
    /// axes (`None` for a local frame).
    pub fn ecef_from_frame(&self) -> Option<(Vector3<f64>, Matrix3<f64>)> {
        match self {
            ExportFrame::Local => None,
            ExportFrame::Topocentric {
                ecef_origin,
                enu_from_ecef,
                ..
            } => Some((*ecef_origin, enu_from_ecef.transpose())),
        }
    }

    /// A world point in the export frame.
    pub fn point(&self, world: &Vector3<f64>) -> Result<Vector3<f64>, IoError> {
        match self {
            ExportFrame::Local => Ok(*world),
            ExportFrame::Topocentric {
                projector,
                ecef_origin,
                enu_from_ecef,
                ..
            } => {
                let (lat, lon) = projector.unproject(world.x, world.y)?;
                Ok(enu_from_ecef * (ecef_from_geodetic(lat, lon, world.z) - ecef_origin))
            }
        }
    }

    /// A camera pose (`cam_from_world`) in the export frame: the centre converted exactly, the
    /// rotation composed with the local frame's rotation at the centre.
    pub fn pose(&self, cam_from_world: &Pose) -> Result<Pose, IoError> {
        if let ExportFrame::Local = self {
            return Ok(*cam_from_world);
        }
        let c = cam_from_world.center();
        // Jacobian of world → frame at the centre by central differences over ±1 m.
        let mut jacobian = Matrix3::zeros();
        for k in 0..3 {
            let mut d = Vector3::zeros();
            d[k] = 1.0;
            let column = (self.point(&(c + d))? - self.point(&(c - d))?) / 2.0;
            jacobian.set_column(k, &column);
        }
        // Its rotation part (polar decomposition): frame_from_world.
        let svd = jacobian.svd(true, true);
        let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
            return Err(IoError::Crs {
                crs: "export frame".into(),
                message: format!("no rotation of the frame at {c:?}"),
            });
        };
        let mut frame_from_world = u * v_t;
        if frame_from_world.determinant() < 0.0 {
            return Err(IoError::Crs {
                crs: "export frame".into(),
                message: "the conversion mirrors the frame".into(),
            });
        }
        // Re-orthonormalise against rounding.
        frame_from_world = Rotation3::from_matrix(&frame_from_world).into_inner();
        let cam_from_frame = cam_from_world.rotation_matrix() * frame_from_world.transpose();
        let rotation = UnitQuaternion::from_matrix(&cam_from_frame);
        Ok(Pose::from_rotation_and_center(rotation, &self.point(&c)?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn geocentric_axes_and_a_known_point() {
        // The equator at Greenwich: (a, 0, 0); the pole: (0, 0, b).
        let p = ecef_from_geodetic(0.0, 0.0, 0.0);
        assert!((p - Vector3::new(A, 0.0, 0.0)).norm() < 1e-6);
        let pole = ecef_from_geodetic(90.0, 0.0, 100.0);
        assert!((pole.z - (A * (1.0 - F) + 100.0)).abs() < 1e-6, "{pole}");
        // At (0, 0) east is +Y, north +Z, up +X.
        let r = enu_from_ecef(0.0, 0.0);
        assert!((r * Vector3::y() - Vector3::x()).norm() < 1e-12);
        assert!((r * Vector3::z() - Vector3::y()).norm() < 1e-12);
        assert!((r * Vector3::x() - Vector3::z()).norm() < 1e-12);
    }

    #[test]
    fn topocentric_frame_keeps_distances_and_turns_by_the_convergence() {
        // UTM 32N, 3° east of the central meridian at 45° N: convergence ≈ sin(45°)·3° ≈ 2.12°.
        let projector = Projector::new(Crs::Epsg(32632)).expect("utm");
        let (e, n) = projector.project(45.0, 12.0).expect("project");
        let centre = Vector3::new(e, n, 500.0);
        let frame = ExportFrame::new(Crs::Epsg(32632), centre).expect("frame");
        let origin = frame.point(&centre).expect("origin");
        assert!(origin.norm() < 1e-6, "{origin}");
        // A point 100 m grid-north: in ENU it is about 100 / k m away (k ≈ 0.99975 there),
        // turned by the convergence.
        let north = frame
            .point(&(centre + Vector3::new(0.0, 100.0, 0.0)))
            .expect("point");
        let turn = north.x.atan2(north.y).to_degrees();
        assert!((turn.abs() - 2.12).abs() < 0.02, "{turn}");
        assert!((north.norm() - 100.0).abs() < 0.1, "{}", north.norm());
        // A nadir camera keeps looking straight down, its centre exactly converted.
        let down = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
        let cam =
            Pose::from_rotation_and_center(down, &(centre + Vector3::new(30.0, -20.0, 120.0)));
        let moved = frame.pose(&cam).expect("pose");
        let axis = moved.rotation.inverse() * Vector3::z();
        assert!(
            (axis - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-3,
            "{axis}"
        );
        let c = frame.point(&cam.center()).expect("centre");
        assert!((moved.center() - c).norm() < 1e-9);
        assert!(matches!(
            ExportFrame::new(Crs::Local, centre),
            Ok(ExportFrame::Local)
        ));
    }
}
