//! Random well-conditioned two-view and absolute-pose scenes for the solver tests.
#![allow(dead_code)]

use nalgebra::{Matrix3, UnitQuaternion, Vector2, Vector3};
use timesift_core::{BrownCamera, CameraModel, Pose, SeededRng};

/// Focal length of the synthetic camera, pixels; converts angular noise to pixels.
pub const FOCAL: f64 = 1000.0;

pub fn camera() -> BrownCamera {
    let mut c = BrownCamera::new(1600, 1200, FOCAL).unwrap();
    c.k1 = -0.08;
    c.k2 = 0.01;
    c.p1 = 2e-4;
    c
}

pub fn random_rotation(rng: &mut SeededRng, max_angle: f64) -> UnitQuaternion<f64> {
    let axis = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
    UnitQuaternion::from_scaled_axis(axis * rng.uniform_range(0.0, max_angle))
}

/// Two cameras: `cam1` at the identity, `cam2` rotated up to 0.3 rad and translated by a baseline
/// of length 1 mostly sideways; `n` points at depths 3–8 inside both fields of view.
pub struct TwoView {
    pub cam2_from_cam1: Pose,
    pub points: Vec<Vector3<f64>>,
    /// Rays with z = 1 in each camera.
    pub x1: Vec<Vector3<f64>>,
    pub x2: Vec<Vector3<f64>>,
}

pub fn two_view(rng: &mut SeededRng, n: usize, planar: bool) -> TwoView {
    let rotation = random_rotation(rng, 0.3);
    let dir = Vector3::new(
        1.0,
        rng.uniform_range(-0.3, 0.3),
        rng.uniform_range(-0.3, 0.3),
    )
    .normalize();
    let center2 = dir;
    let pose = Pose::from_rotation_and_center(rotation, &center2);
    let mut points = Vec::new();
    let mut x1 = Vec::new();
    let mut x2 = Vec::new();
    let plane_n = Vector3::new(0.1, -0.2, 1.0).normalize();
    while points.len() < n {
        let ray = Vector3::new(
            rng.uniform_range(-0.4, 0.4),
            rng.uniform_range(-0.3, 0.3),
            1.0,
        );
        let depth = if planar {
            // Points on the plane n·X = 5.
            5.0 / plane_n.dot(&ray)
        } else {
            rng.uniform_range(3.0, 8.0)
        };
        let p = ray * depth;
        let q = pose.transform_point(&p);
        if q.z < 1.0 || (q.x / q.z).abs() > 0.6 || (q.y / q.z).abs() > 0.5 {
            continue;
        }
        points.push(p);
        x1.push(p / p.z);
        x2.push(q / q.z);
    }
    TwoView {
        cam2_from_cam1: pose,
        points,
        x1,
        x2,
    }
}

/// Adds Gaussian noise of `sigma_px` pixels to z = 1 rays (through the focal length).
pub fn noisy(rng: &mut SeededRng, x: &[Vector3<f64>], sigma_px: f64) -> Vec<Vector3<f64>> {
    x.iter()
        .map(|v| {
            Vector3::new(
                v.x + rng.normal() * sigma_px / FOCAL,
                v.y + rng.normal() * sigma_px / FOCAL,
                1.0,
            )
        })
        .collect()
}

/// Pixels of z = 1 rays through a pinhole of focal FOCAL centred at (800, 600).
pub fn pixels(x: &[Vector3<f64>]) -> Vec<Vector2<f64>> {
    x.iter()
        .map(|v| Vector2::new(800.0 + FOCAL * v.x, 600.0 + FOCAL * v.y))
        .collect()
}

pub fn essential_of(pose: &Pose) -> Matrix3<f64> {
    let e = pose.translation.normalize().cross_matrix() * pose.rotation_matrix();
    e / e.norm()
}

/// Distance between two matrices up to scale and sign (both normalised first).
pub fn projective_distance(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    let (a, b) = (a / a.norm(), b / b.norm());
    (a - b).norm().min((a + b).norm())
}

/// An absolute-pose scene: a camera looking at `n` points at depth 4–12 spread in 3-D (or on a
/// plane), with their pixels through the distorted camera.
pub struct AbsoluteScene {
    pub pose: Pose,
    pub world: Vec<Vector3<f64>>,
    pub pixels: Vec<Vector2<f64>>,
    pub rays: Vec<Vector3<f64>>,
}

pub fn absolute_scene(
    rng: &mut SeededRng,
    cam: &BrownCamera,
    n: usize,
    planar: bool,
) -> AbsoluteScene {
    let rotation = random_rotation(rng, std::f64::consts::PI);
    let center = Vector3::new(
        rng.uniform_range(-50.0, 50.0),
        rng.uniform_range(-50.0, 50.0),
        rng.uniform_range(-50.0, 50.0),
    );
    let pose = Pose::from_rotation_and_center(rotation, &center);
    let world_from_cam = pose.inverse();
    let mut world = Vec::new();
    let mut pixels = Vec::new();
    let mut rays = Vec::new();
    while world.len() < n {
        let u = Vector2::new(
            rng.uniform_range(50.0, 1550.0),
            rng.uniform_range(50.0, 1150.0),
        );
        let ray = cam.unproject(&u).unwrap();
        let depth = if planar {
            8.0
        } else {
            rng.uniform_range(4.0, 12.0)
        };
        world.push(world_from_cam.transform_point(&(ray * depth)));
        pixels.push(u);
        rays.push(ray);
    }
    AbsoluteScene {
        pose,
        world,
        pixels,
        rays,
    }
}

pub fn pose_error(a: &Pose, b: &Pose) -> (f64, f64) {
    (
        a.rotation.angle_to(&b.rotation),
        (a.center() - b.center()).norm(),
    )
}
