//! Rendered test scenes with exact depths: a textured plane seen from a nadir block, and a
//! sphere on the ground seen from a ring of oblique cameras.

#![allow(dead_code)]

use nalgebra::Vector3;
use timesift_core::{BrownCamera, Camera, Pose, SeededRng};
use timesift_dense::{EpochInput, ImageView, SparsePoint, View, WorkingCamera};
use timesift_synth::noise::Noise;
use timesift_synth::render::{Material, RenderOptions, Scene, render};

/// Distance of a world point to the true surface, metres.
pub type DistanceFn = Box<dyn Fn(&Vector3<f64>) -> f64>;
/// Whether a true surface point belongs to the object under test.
pub type ObjectFn = Box<dyn Fn(&Vector3<f64>) -> bool>;

/// A rendered epoch: views, sparse points, images (RGB interleaved) and the scene for truth.
pub struct Rendered {
    pub input: EpochInput,
    pub images: Vec<Vec<f32>>,
    pub size: (usize, usize),
    pub scene: Scene,
    /// Distance of a world point to the true surface, metres.
    pub distance: DistanceFn,
    /// Whether a true surface point belongs to the object under test.
    pub object: ObjectFn,
}

impl Rendered {
    pub fn views(&self) -> Vec<ImageView<'_>> {
        self.images
            .iter()
            .map(|d| ImageView {
                width: self.size.0,
                height: self.size.1,
                channels: 3,
                data: d,
            })
            .collect()
    }

    /// The true depth along the ray of pixel centre (u, v) of a working camera of view `view`,
    /// where the ray meets the object under test.
    pub fn true_depth(&self, view: usize, camera: &WorkingCamera, u: f64, v: f64) -> Option<f64> {
        let pose = &self.input.views[view].cam_from_world;
        let ray_cam = camera.ray(u, v);
        let world_from_cam = pose.rotation.inverse();
        let dir = (world_from_cam * ray_cam).normalize();
        let hit = self.scene.hit(&pose.center(), &dir)?;
        (self.object)(&hit).then(|| pose.transform_point(&hit).z)
    }

    /// How many of the views have world point `p` in their field (in front, inside the image
    /// less a border of `inset` pixels), occlusion aside.
    pub fn views_with_in_field(&self, p: &Vector3<f64>, inset: f64) -> usize {
        let (w, h) = (self.size.0 as f64 - inset, self.size.1 as f64 - inset);
        self.input
            .views
            .iter()
            .filter(|v| {
                v.cam_from_world.transform_point(p).z > 0.0
                    && timesift_core::project_world(&v.camera, &v.cam_from_world, p)
                        .is_ok_and(|q| q.x >= inset && q.y >= inset && q.x < w && q.y < h)
            })
            .count()
    }

    /// Distance of a world point to the true surface in pixel footprints of the nearest camera
    /// (its distance over the focal length).
    pub fn surface_error_px(&self, p: &Vector3<f64>, f: f64) -> f64 {
        let nearest = self
            .input
            .views
            .iter()
            .map(|v| (v.cam_from_world.center() - p).norm())
            .fold(f64::INFINITY, f64::min);
        (self.distance)(p) * f / nearest
    }
}

fn camera(width: u32, height: u32, f: f64) -> Camera {
    let mut b = BrownCamera::new(width, height, f).expect("camera");
    b.k1 = -0.05;
    b.k2 = 0.01;
    b.cx = 1.5;
    b.cy = -1.0;
    Camera::Brown(b)
}

fn cover(seed: u64) -> Material {
    Material::Cover {
        noise: Box::new(Noise::new(seed)),
        dark: Vector3::new(0.25, 0.22, 0.18),
        light: Vector3::new(0.7, 0.65, 0.55),
        scale: 2.0,
        octaves: 7,
        contrast: 1.3,
        speckle: 0.45,
        speckle_seed: seed ^ 77,
    }
}

fn render_all(
    scene: Scene,
    camera: Camera,
    poses: Vec<Pose>,
    points: Vec<Vector3<f64>>,
    distance: DistanceFn,
    object: ObjectFn,
) -> Rendered {
    let (w, h) = match &camera {
        Camera::Brown(b) => (b.width as usize, b.height as usize),
        Camera::Pinhole(p) => (p.width as usize, p.height as usize),
    };
    let options = RenderOptions {
        supersampling: 2,
        shadows: false,
    };
    let mut rng = SeededRng::new(5);
    let images = poses
        .iter()
        .map(|pose| {
            let img = render(&scene, &camera, w, h, pose, &options).expect("render");
            img.data
                .iter()
                .flat_map(|p| p.iter().copied())
                .map(|c| (c + 0.004 * rng.normal() as f32).clamp(0.0, 1.0))
                .collect::<Vec<f32>>()
        })
        .collect();
    let views: Vec<View> = poses
        .iter()
        .map(|p| View {
            camera: camera.clone(),
            cam_from_world: *p,
        })
        .collect();
    let sparse = points
        .iter()
        .filter_map(|x| {
            let seen: Vec<usize> = views
                .iter()
                .enumerate()
                .filter(|(_, v)| {
                    let pc = v.cam_from_world.transform_point(x);
                    let centre = v.cam_from_world.center();
                    pc.z > 0.0
                        && timesift_core::project_world(&v.camera, &v.cam_from_world, x).is_ok_and(
                            |p| p.x > 0.0 && p.y > 0.0 && p.x < w as f64 && p.y < h as f64,
                        )
                        && scene.sees(&centre, x, 1e-3)
                })
                .map(|(k, _)| k)
                .collect();
            (seen.len() >= 2).then_some(SparsePoint {
                position: *x,
                views: seen,
            })
        })
        .collect();
    Rendered {
        input: EpochInput {
            views,
            points: sparse,
        },
        images,
        size: (w, h),
        scene,
        distance,
        object,
    }
}

/// A plane tilted by about 8° under a 3 × 2 nadir block 10 m above it, in UTM-sized
/// coordinates.
pub fn plane(width: u32, height: u32) -> Rendered {
    // Converging on the origin's north-south line, to within 0.1 m.
    let cameras = [(0, 0), (1, 0), (2, 0), (0, 1), (1, 1), (2, 1)].map(|(i, j)| {
        (
            -3.0 + 3.0 * i as f64,
            -1.5 + 3.0 * j as f64,
            0.1 * (i as f64 - 1.0),
        )
    });
    plane_under(width, height, &cameras)
}

/// The plane of [`plane`] under cameras 10 m above it: `(east, north, aim)` offsets from the
/// scene's origin, metres, each looking at the point `aim` east of the origin on its
/// north-south line.
pub fn plane_under(width: u32, height: u32, cameras: &[(f64, f64, f64)]) -> Rendered {
    let origin = Vector3::new(500_000.0, 5_000_000.0, 200.0);
    let slope = 0.14;
    let z = move |x: f64, y: f64| origin.z + slope * (x - origin.x) - 0.05 * (y - origin.y);
    let s = 40.0;
    let corners = [(-s, -s), (s, -s), (s, s), (-s, s)];
    let vertices: Vec<Vector3<f64>> = corners
        .iter()
        .map(|&(dx, dy)| {
            let (x, y) = (origin.x + dx, origin.y + dy);
            Vector3::new(x, y, z(x, y))
        })
        .collect();
    let scene = Scene::new(
        &vertices,
        &[[0, 1, 2], [0, 2, 3]],
        vec![0, 0],
        vec![cover(11)],
    )
    .expect("scene");
    let f = 0.8 * width as f64;
    let cam = camera(width, height, f);
    let poses = cameras
        .iter()
        .map(|&(dx, dy, aim)| {
            let c = Vector3::new(origin.x + dx, origin.y + dy, origin.z + 10.0);
            let target = Vector3::new(origin.x + aim, origin.y + dy, origin.z);
            nadir_towards(&c, &target)
        })
        .collect();
    // Sparse points every 0.6 m over the block's centres and 4.2 m around them.
    let reach = cameras
        .iter()
        .fold(0.0f64, |m, &(dx, dy, _)| m.max(dx.abs()).max(dy.abs()));
    let n = ((reach + 4.2) / 0.6).round() as i64;
    let mut points = Vec::new();
    for a in -n..=n {
        for b in -n..=n {
            let (x, y) = (origin.x + 0.6 * a as f64, origin.y + 0.6 * b as f64);
            points.push(Vector3::new(x, y, z(x, y)));
        }
    }
    let normal = Vector3::new(-slope, 0.05, 1.0).normalize();
    let distance = Box::new(move |p: &Vector3<f64>| (p.z - z(p.x, p.y)).abs() * normal.z);
    render_all(scene, cam, poses, points, distance, Box::new(|_| true))
}

/// A camera at `c` looking at `target` with image rows towards south (x east, y south).
fn nadir_towards(c: &Vector3<f64>, target: &Vector3<f64>) -> Pose {
    let z = (target - c).normalize();
    let x = Vector3::new(1.0, 0.0, 0.0);
    let x = (x - z * z.dot(&x)).normalize();
    let y = z.cross(&x);
    let r = nalgebra::Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
    let rot = nalgebra::UnitQuaternion::from_rotation_matrix(
        &nalgebra::Rotation3::from_matrix_unchecked(r),
    );
    Pose::from_rotation_and_center(rot, c)
}

/// A sphere of radius 1 m on a ground plane, seen by twelve cameras on a ring 4 m away and 2.5 m
/// up, looking at it.
pub fn sphere(width: u32, height: u32) -> Rendered {
    let centre = Vector3::new(0.0, 0.0, 1.0);
    let radius = 1.0;
    let (mut vertices, mut triangles) = (Vec::new(), Vec::new());
    let (rings, segments) = (60u32, 120u32);
    for i in 0..=rings {
        let theta = std::f64::consts::PI * i as f64 / rings as f64;
        for j in 0..segments {
            let phi = std::f64::consts::TAU * j as f64 / segments as f64;
            vertices.push(
                centre
                    + radius
                        * Vector3::new(
                            theta.sin() * phi.cos(),
                            theta.sin() * phi.sin(),
                            theta.cos(),
                        ),
            );
        }
    }
    for i in 0..rings {
        for j in 0..segments {
            let a = i * segments + j;
            let b = i * segments + (j + 1) % segments;
            let c = (i + 1) * segments + j;
            let d = (i + 1) * segments + (j + 1) % segments;
            triangles.push([a, c, b]);
            triangles.push([b, c, d]);
        }
    }
    let sphere_triangles = triangles.len();
    let base = vertices.len() as u32;
    let g = 8.0;
    for (x, y) in [(-g, -g), (g, -g), (g, g), (-g, g)] {
        vertices.push(Vector3::new(x, y, 0.0));
    }
    triangles.push([base, base + 1, base + 2]);
    triangles.push([base, base + 2, base + 3]);
    let mut materials = vec![0; sphere_triangles];
    materials.extend([1, 1]);
    let mut sphere_cover = cover(21);
    if let Material::Cover { scale, .. } = &mut sphere_cover {
        *scale = 0.5;
    }
    let scene = Scene::new(
        &vertices,
        &triangles,
        materials,
        vec![sphere_cover, cover(22)],
    )
    .expect("scene");
    let f = 0.9 * width as f64;
    let cam = camera(width, height, f);
    let poses: Vec<Pose> = (0..12)
        .map(|k| {
            let a = std::f64::consts::TAU * k as f64 / 12.0;
            let c = Vector3::new(4.0 * a.cos(), 4.0 * a.sin(), 2.5);
            Pose::look_at(&c, &centre).expect("pose")
        })
        .collect();
    let mut points = Vec::new();
    let mut rng = SeededRng::new(9);
    for _ in 0..600 {
        let v = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
        points.push(centre + radius * v);
    }
    let distance =
        Box::new(move |p: &Vector3<f64>| ((p - centre).norm() - radius).abs().min(p.z.abs()));
    let object = Box::new(move |p: &Vector3<f64>| ((p - centre).norm() - radius).abs() < 0.01);
    render_all(scene, cam, poses, points, distance, object)
}

/// Crowns on flat ground, as an orchard's trees: (x, y, radius, height), metres.
pub const CROWNS: [(f64, f64, f64, f64); 6] = [
    (-2.0, -1.5, 0.65, 1.1),
    (0.2, -1.8, 0.6, 1.0),
    (2.3, -1.2, 0.7, 1.2),
    (-1.6, 1.4, 0.7, 1.1),
    (0.6, 1.1, 0.6, 1.2),
    (2.6, 1.8, 0.65, 1.0),
];

/// Height of the crowns' scene at (x, y): each crown `h (1 − r²/R²)²` inside its radius R (a
/// rounded dome whose flanks are steeper than 50°), 0 elsewhere.
pub fn crown_height(x: f64, y: f64) -> f64 {
    CROWNS
        .iter()
        .map(|&(cx, cy, r, h)| {
            let q = ((x - cx).powi(2) + (y - cy).powi(2)) / (r * r);
            if q < 1.0 { h * (1.0 - q).powi(2) } else { 0.0 }
        })
        .fold(0.0, f64::max)
}

/// Whether (x, y) is within a crown's radius grown by `margin` metres.
pub fn near_crown(x: f64, y: f64, margin: f64) -> bool {
    CROWNS
        .iter()
        .any(|&(cx, cy, r, _)| (x - cx).hypot(y - cy) < r + margin)
}

/// Six narrow crowns on textured flat ground (a 0.04 m mesh of [`crown_height`]) under a
/// 3 × 2 nadir block 10 m up: at half resolution a crown is about 10 pixels across, so a
/// matching window of 11 pixels on its flank always holds crown and ground.
pub fn crowns(width: u32, height: u32) -> Rendered {
    let (half, step): (f64, f64) = (9.5, 0.04);
    let n = (2.0 * half / step).round() as u32;
    let mut vertices = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (-half + step * i as f64, -half + step * j as f64);
            vertices.push(Vector3::new(x, y, crown_height(x, y)));
        }
    }
    let (mut triangles, mut materials) = (Vec::new(), Vec::new());
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i;
            let (b, c, d) = (a + 1, a + n + 1, a + n + 2);
            let centre = vertices[a as usize] + vertices[d as usize];
            let material = usize::from(near_crown(centre.x / 2.0, centre.y / 2.0, 0.0));
            triangles.push([a, b, d]);
            triangles.push([a, d, c]);
            materials.extend([material, material]);
        }
    }
    let mut crown_cover = cover(31);
    if let Material::Cover {
        scale, dark, light, ..
    } = &mut crown_cover
    {
        *scale = 0.5;
        *dark = Vector3::new(0.04, 0.1, 0.03);
        *light = Vector3::new(0.25, 0.45, 0.2);
    }
    let scene = Scene::new(
        &vertices,
        &triangles,
        materials,
        vec![cover(32), crown_cover],
    )
    .expect("scene");
    let f = 0.8 * width as f64;
    let cam = camera(width, height, f);
    let mut poses = Vec::new();
    for (i, j) in [(0, 0), (1, 0), (2, 0), (0, 1), (1, 1), (2, 1)] {
        let c = Vector3::new(-2.5 + 2.5 * i as f64, -1.25 + 2.5 * j as f64, 10.0);
        let target = Vector3::new(0.1 * (i as f64 - 1.0), 0.0, 0.0);
        poses.push(nadir_towards(&c, &target));
    }
    let mut points = Vec::new();
    for a in -10..=10 {
        for b in -8..=8 {
            let (x, y) = (0.5 * a as f64, 0.5 * b as f64);
            points.push(Vector3::new(x, y, crown_height(x, y)));
        }
    }
    let distance = Box::new(|p: &Vector3<f64>| (p.z - crown_height(p.x, p.y)).abs());
    render_all(scene, cam, poses, points, distance, Box::new(|_| true))
}
