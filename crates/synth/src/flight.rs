//! Camera placement as surveys are flown or walked: serpentine nadir blocks at a given overlap,
//! rings of oblique views, convergent arcs in front of a wall; with the small attitude and
//! position scatter of real platforms, drawn from a seeded generator.

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use timesift_core::{BrownCamera, Pose, SeededRng};

/// A nadir block over a rectangle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NadirBlock {
    /// South-west corner of the area to cover (x, y).
    pub min: (f64, f64),
    /// North-east corner.
    pub max: (f64, f64),
    /// Flying height (local z of the cameras).
    pub altitude: f64,
    /// Mean ground height, for the footprint.
    pub ground: f64,
    /// Forward overlap (0–1).
    pub forward: f64,
    /// Side overlap (0–1).
    pub side: f64,
    /// Attitude scatter, radians (1σ).
    pub tilt_sigma: f64,
    /// Position scatter, metres (1σ).
    pub position_sigma: f64,
}

/// Camera looking straight down with heading `heading` (image x axis along (cos, sin, 0)).
pub fn nadir_rotation(heading: f64) -> UnitQuaternion<f64> {
    let x = Vector3::new(heading.cos(), heading.sin(), 0.0);
    let z = Vector3::new(0.0, 0.0, -1.0);
    let y = z.cross(&x);
    let r = Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r))
}

/// Perturbs a pose's attitude by small random rotations (in the camera frame) and its centre.
pub fn jitter(pose: &Pose, tilt_sigma: f64, position_sigma: f64, rng: &mut SeededRng) -> Pose {
    let d = UnitQuaternion::from_scaled_axis(Vector3::new(
        tilt_sigma * rng.normal(),
        tilt_sigma * rng.normal(),
        tilt_sigma * rng.normal(),
    ));
    let c = pose.center()
        + Vector3::new(
            position_sigma * rng.normal(),
            position_sigma * rng.normal(),
            position_sigma * rng.normal(),
        );
    Pose::from_rotation_and_center(d * pose.rotation, &c)
}

impl NadirBlock {
    /// The camera poses (`cam_from_local`): strips along x, alternating heading, centred on the
    /// area.
    pub fn poses(&self, camera: &BrownCamera, rng: &mut SeededRng) -> Vec<Pose> {
        let range = self.altitude - self.ground;
        let along = range * camera.width as f64 / camera.f * (1.0 - self.forward);
        let across = range * camera.height as f64 / camera.f * (1.0 - self.side);
        let (lx, ly) = (self.max.0 - self.min.0, self.max.1 - self.min.1);
        let nx = (lx / along).ceil().max(0.0) as usize + 1;
        let ny = (ly / across).ceil().max(0.0) as usize + 1;
        let x0 = 0.5 * (self.min.0 + self.max.0) - 0.5 * (nx - 1) as f64 * along;
        let y0 = 0.5 * (self.min.1 + self.max.1) - 0.5 * (ny - 1) as f64 * across;
        let mut poses = Vec::with_capacity(nx * ny);
        for j in 0..ny {
            let forward_strip = j % 2 == 0;
            let heading = if forward_strip {
                0.0
            } else {
                std::f64::consts::PI
            };
            for k in 0..nx {
                let i = if forward_strip { k } else { nx - 1 - k };
                let c = Vector3::new(x0 + i as f64 * along, y0 + j as f64 * across, self.altitude);
                let pose = Pose::from_rotation_and_center(nadir_rotation(heading), &c);
                poses.push(jitter(&pose, self.tilt_sigma, self.position_sigma, rng));
            }
        }
        poses
    }
}

/// `n` cameras on a horizontal circle of `radius` around `centre` at height `z`, all looking at
/// `target`.
pub fn ring(
    centre: (f64, f64),
    radius: f64,
    z: f64,
    target: &Vector3<f64>,
    n: usize,
    rng: &mut SeededRng,
) -> Vec<Pose> {
    (0..n)
        .filter_map(|k| {
            let a = 2.0 * std::f64::consts::PI * (k as f64 + 0.5) / n as f64;
            let c = Vector3::new(centre.0 + radius * a.cos(), centre.1 + radius * a.sin(), z);
            Pose::look_at(&c, target).map(|p| jitter(&p, 0.01, 0.2, rng))
        })
        .collect()
}
