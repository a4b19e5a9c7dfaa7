//! What the report computes from the products rather than reads: image footprints on the ground,
//! the overlap of images per DEM cell, reprojection errors per observation, and the epoch ×
//! epoch connectivity of the tie points.

use std::collections::BTreeMap;

use nalgebra::{Vector2, Vector3};
use rayon::prelude::*;
use timesift_core::{Camera, CameraModel, Pose};
use timesift_io::cameras_json::Reconstruction;
use timesift_io::colmap::{ColmapModel, camera_from_colmap};
use timesift_io::geotiff::GeoRaster;
use timesift_io::ply::TiePoint;

/// An oriented image as the maps draw it.
#[derive(Debug, Clone, PartialEq)]
pub struct Footprint {
    /// Camera centre (x, y).
    pub centre: [f64; 2],
    /// The image border projected onto the ground plane, when the whole border looks down.
    pub outline: Option<Vec<[f64; 2]>>,
}

/// Footprints of an epoch's oriented images on the horizontal plane at `ground_height`: the image
/// border (corners and edge midpoints) cast through the camera model.
pub fn footprints(recon: &Reconstruction, epoch: &str, ground_height: f64) -> Vec<Footprint> {
    recon
        .images
        .iter()
        .filter(|i| i.epoch == epoch)
        .filter_map(|i| {
            let pose = i.pose.as_ref()?;
            let camera = recon.cameras.get(&i.camera)?;
            let c = pose.center();
            Some(Footprint {
                centre: [c.x, c.y],
                outline: outline(camera, pose, ground_height),
            })
        })
        .collect()
}

fn outline(camera: &Camera, pose: &Pose, ground_height: f64) -> Option<Vec<[f64; 2]>> {
    let (w, h) = (camera.width() as f64, camera.height() as f64);
    let border = [
        (0.0, 0.0),
        (0.5, 0.0),
        (1.0, 0.0),
        (1.0, 0.5),
        (1.0, 1.0),
        (0.5, 1.0),
        (0.0, 1.0),
        (0.0, 0.5),
    ];
    let world_from_cam = pose.inverse();
    let centre = pose.center();
    let height_above = centre.z - ground_height;
    if height_above <= 0.0 {
        return None;
    }
    border
        .iter()
        .map(|&(fx, fy)| {
            let ray_cam = camera.unproject(&Vector2::new(fx * w, fy * h)).ok()?;
            let ray = world_from_cam.rotation_matrix() * ray_cam;
            // Rays near the horizon would reach far beyond the survey: not drawn.
            if ray.z >= -0.05 * ray.norm() {
                return None;
            }
            let t = (ground_height - centre.z) / ray.z;
            let p = centre + ray * t;
            Some([p.x, p.y])
        })
        .collect()
}

/// Images of `epoch` that see each sampled DEM cell (inside the image, in front of the camera;
/// occlusion ignored): counts on a lattice of every `step`-th cell, row-major, `None` where the
/// DEM has no height.
pub fn overlap(
    dem: &GeoRaster<f32>,
    recon: &Reconstruction,
    epoch: &str,
    step: usize,
) -> (usize, usize, Vec<Option<u16>>) {
    let step = step.max(1);
    let (cols, rows) = (dem.width.div_ceil(step), dem.height.div_ceil(step));
    let views: Vec<(&Camera, &Pose)> = recon
        .images
        .iter()
        .filter(|i| i.epoch == epoch)
        .filter_map(|i| Some((recon.cameras.get(&i.camera)?, i.pose.as_ref()?)))
        .collect();
    let nodata = dem.georef.nodata;
    let t = dem.georef.transform;
    let counts = (0..rows * cols)
        .into_par_iter()
        .map(|k| {
            let (c, r) = ((k % cols) * step, (k / cols) * step);
            let z = dem.data[r * dem.width + c];
            if !z.is_finite() || nodata.is_some_and(|n| z as f64 == n) {
                return None;
            }
            let (x, y) = t.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
            let p = Vector3::new(x, y, z as f64);
            let seen = views
                .iter()
                .filter(|(camera, pose)| {
                    let q = pose.transform_point(&p);
                    q.z > 0.0
                        && camera.project(&q).is_ok_and(|px| {
                            px.x >= 0.0
                                && px.y >= 0.0
                                && px.x < camera.width() as f64
                                && px.y < camera.height() as f64
                        })
                })
                .count();
            Some(seen.min(u16::MAX as usize) as u16)
        })
        .collect();
    (cols, rows, counts)
}

/// Colour of an overlap count: red where no stereo is possible, through yellow to green.
pub fn overlap_colour(count: u16) -> [u8; 3] {
    match count {
        0 => [120, 120, 120],
        1 => [215, 48, 39],
        2 => [252, 141, 89],
        3..=4 => [254, 224, 139],
        5..=8 => [145, 207, 96],
        _ => [26, 152, 80],
    }
}

/// Legend of [`overlap_colour`].
pub const OVERLAP_LEGEND: [(u16, &str); 6] = [
    (0, "0"),
    (1, "1"),
    (2, "2"),
    (3, "3–4"),
    (5, "5–8"),
    (9, "≥ 9"),
];

/// Reprojection error of every observation of the COLMAP model, pixels, by the epoch of its image
/// (the epoch recorded in the model, else the one `recon` gives the image's name).
pub fn reprojection_errors(
    model: &ColmapModel,
    recon: &Reconstruction,
) -> BTreeMap<String, Vec<f64>> {
    let epoch_of: BTreeMap<&str, &str> = recon
        .images
        .iter()
        .map(|i| (i.name.as_str(), i.epoch.as_str()))
        .collect();
    let cameras: BTreeMap<u32, Camera> = model
        .cameras
        .iter()
        .filter_map(|(&id, c)| {
            Some((
                id,
                camera_from_colmap(&c.model, c.width, c.height, &c.params).ok()?,
            ))
        })
        .collect();
    let mut out: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    for image in model.images.values() {
        let Some(camera) = cameras.get(&image.camera_id) else {
            continue;
        };
        let epoch = image
            .epoch
            .as_deref()
            .or_else(|| epoch_of.get(image.name.as_str()).copied())
            .unwrap_or("?");
        let errors = out.entry(epoch.to_string()).or_default();
        for &(u, v, pid) in &image.points2d {
            let Some(point) = u64::try_from(pid).ok().and_then(|p| model.points.get(&p)) else {
                continue;
            };
            if let Ok(px) = camera.project(&image.pose.transform_point(&point.xyz)) {
                errors.push((px.x - u).hypot(px.y - v));
            }
        }
    }
    out
}

/// Tie points seen by both epochs of every pair (the diagonal: all tie points of the epoch).
pub fn tie_matrix(epochs: usize, points: &[TiePoint]) -> Vec<Vec<usize>> {
    let mut m = vec![vec![0usize; epochs]; epochs];
    for p in points {
        for (a, row) in m.iter_mut().enumerate() {
            if !p.epochs.contains(a) {
                continue;
            }
            for (b, cell) in row.iter_mut().enumerate() {
                if p.epochs.contains(b) {
                    *cell += 1;
                }
            }
        }
    }
    m
}

/// Fraction of an epoch's tie-point extent that its inter-epoch tie points span: the area of the
/// 5–95 % box of the inter-epoch points over that of all the epoch's points (1 when they span
/// it all). `None` when either set has fewer than ten points.
pub fn tie_spread(points: &[TiePoint], epoch: usize) -> Option<f64> {
    let all: Vec<&TiePoint> = points.iter().filter(|p| p.epochs.contains(epoch)).collect();
    let inter: Vec<&TiePoint> = all
        .iter()
        .copied()
        .filter(|p| p.epochs.has_other_than(epoch))
        .collect();
    if all.len() < 10 || inter.len() < 10 {
        return None;
    }
    let area = |set: &[&TiePoint]| {
        let mut xs: Vec<f64> = set.iter().map(|p| p.position.x).collect();
        let mut ys: Vec<f64> = set.iter().map(|p| p.position.y).collect();
        xs.sort_by(f64::total_cmp);
        ys.sort_by(f64::total_cmp);
        let q = |v: &[f64], f: f64| v[((v.len() - 1) as f64 * f).round() as usize];
        (q(&xs, 0.95) - q(&xs, 0.05)) * (q(&ys, 0.95) - q(&ys, 0.05))
    };
    let whole = area(&all);
    (whole > 0.0).then(|| (area(&inter) / whole).min(1.0))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;
    use timesift_core::PinholeCamera;
    use timesift_io::cameras_json::OrientedImage;

    fn nadir_block() -> Reconstruction {
        // A 1000 × 800 px pinhole, f = 1000 px, 100 m above ground at z = 0, looking down.
        let camera = Camera::Pinhole(PinholeCamera::new(1000, 800, 1000.0).expect("camera"));
        let down = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
        let pose = Pose::from_rotation_and_center(down, &Vector3::new(50.0, 20.0, 100.0));
        Reconstruction {
            crs: "local".into(),
            cameras: [("c".to_string(), camera)].into(),
            images: vec![
                OrientedImage {
                    name: "a.jpg".into(),
                    epoch: "e1".into(),
                    camera: "c".into(),
                    pose: Some(pose),
                },
                OrientedImage {
                    name: "b.jpg".into(),
                    epoch: "e1".into(),
                    camera: "c".into(),
                    pose: None,
                },
            ],
        }
    }

    #[test]
    fn a_nadir_footprint_is_the_image_scaled_by_height_over_focal() {
        let recon = nadir_block();
        let f = footprints(&recon, "e1", 0.0);
        assert_eq!(f.len(), 1, "the image without a pose has none");
        let outline = f[0].outline.as_ref().expect("looks down");
        let (xs, ys): (Vec<f64>, Vec<f64>) = outline.iter().map(|p| (p[0], p[1])).unzip();
        let span = |v: &[f64]| {
            v.iter().copied().fold(f64::MIN, f64::max) - v.iter().copied().fold(f64::MAX, f64::min)
        };
        // 1000 px × 100 m / 1000 px = 100 m across, 80 m along.
        assert!((span(&xs) - 100.0).abs() < 1e-6 && (span(&ys) - 80.0).abs() < 1e-6);
        assert_eq!(f[0].centre, [50.0, 20.0]);
        // Above the camera there is no footprint.
        assert!(footprints(&recon, "e1", 150.0)[0].outline.is_none());
    }

    #[test]
    fn tie_matrix_counts_shared_points_and_spread_sees_a_strip() {
        let p = |x: f64, y: f64, epochs: &[usize]| TiePoint {
            position: Vector3::new(x, y, 0.0),
            observations: 2,
            epochs: epochs.iter().copied().collect(),
        };
        let mut points = Vec::new();
        for i in 0..20 {
            for j in 0..20 {
                // Epoch 0 everywhere; epoch 1 shares only a strip x < 2.
                let both = i < 2;
                points.push(p(i as f64, j as f64, if both { &[0, 1] } else { &[0] }));
            }
        }
        let m = tie_matrix(2, &points);
        assert_eq!(m, vec![vec![400, 40], vec![40, 40]]);
        let spread = tie_spread(&points, 0).expect("spread");
        assert!(spread < 0.1, "{spread}");
        assert_eq!(tie_spread(&points, 1), Some(1.0));
    }
}
