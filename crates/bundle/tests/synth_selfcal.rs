//! Self-calibration of the cameras of a `timesift-synth` scene: the first epoch of `orchard` at
//! full scale (48 nadir and 12 oblique 6 MP images, a distorted drone lens, six GCPs). Tie points
//! are true surface points observed where the scene shows them (visibility by ray casting) with
//! 0.5 px noise — features and matching are other stages. From a start with f 2 % off and no
//! distortion, the adjustment with f, cx, cy, k1–k3, p1, p2 free recovers f within 0.1 % and k1
//! within 5 %, and the standard deviations it reports for f and k1 agree with their spread over 50
//! seeded noise realisations within 20 %.

mod common;

use nalgebra::{Vector2, Vector3, Vector6};
use timesift_bundle::precision::{CovarianceScale, precision};
use timesift_bundle::problem::{BundleImage, BundlePoint};
use timesift_bundle::{BundleOptions, BundleProblem, CameraGroup, Observation, PointPrior, solve};
use timesift_core::{BrownCamera, Camera, CameraModel, Pose, SeededRng, project_world};
use timesift_geometry::triangulation::triangulate_dlt;
use timesift_synth::scenes::{Scale, build};

const SIGMA_PX: f64 = 0.5;
const MARKER_PX: f64 = 0.3;
const F: usize = 0;
const K1: usize = 5;
const NUM_POINTS: usize = 1500;
const RUNS: u64 = 50;
const FREE: [&str; 8] = ["f", "cx", "cy", "k1", "k2", "k3", "p1", "p2"];

struct Block {
    camera: BrownCamera,
    poses: Vec<Pose>,
    points: Vec<Vector3<f64>>,
    /// (image, point) pairs where the point is visible.
    visible: Vec<(usize, usize)>,
    /// Indices of GCPs among `points`.
    gcps: Vec<usize>,
}

fn block() -> Block {
    let spec = build("orchard", Scale::Full, 3).expect("scene");
    let field = spec.heightfield(0);
    let scene = spec.scene(&field, 0).expect("scene");
    let epoch = &spec.epochs[0];
    let camera = epoch.camera;
    let poses: Vec<Pose> = epoch.images.iter().map(|i| i.pose).collect();
    let mut rng = SeededRng::new(17);
    let mut points: Vec<Vector3<f64>> = (0..NUM_POINTS)
        .filter_map(|_| {
            let (x, y) = (rng.uniform_range(5.0, 115.0), rng.uniform_range(5.0, 85.0));
            spec.surface(&field, 0, x, y).map(|z| Vector3::new(x, y, z))
        })
        .collect();
    let gcps: Vec<usize> = (points.len()..points.len() + spec.gcps.len()).collect();
    for g in &spec.gcps {
        points.push(spec.point_local(&field, g).expect("gcp"));
    }
    let mut visible = Vec::new();
    for (i, pose) in poses.iter().enumerate() {
        let c = pose.center();
        for (j, x) in points.iter().enumerate() {
            let Ok(px) = project_world(&camera, pose, x) else {
                continue;
            };
            let inside = px.x > 2.0
                && px.y > 2.0
                && px.x < camera.width as f64 - 2.0
                && px.y < camera.height as f64 - 2.0;
            // The brown polynomial folds points far outside the field of view back into the
            // frame: keep only projections whose ray leads back to the point.
            let xc = pose.transform_point(x).normalize();
            let consistent = camera
                .unproject(&px)
                .is_ok_and(|r| r.normalize().dot(&xc) > 1.0 - 1e-9);
            if inside && consistent && scene.sees(&c, x, 1e-6 * (x - c).norm() + 1e-4) {
                visible.push((i, j));
            }
        }
    }
    // Keep points seen at least twice (GCPs carry priors and are kept).
    let mut count = vec![0usize; points.len()];
    for &(_, j) in &visible {
        count[j] += 1;
    }
    let keep: Vec<usize> = (0..points.len())
        .filter(|&j| count[j] >= 2 || gcps.contains(&j))
        .collect();
    let mut new_index = vec![usize::MAX; points.len()];
    for (k, &j) in keep.iter().enumerate() {
        new_index[j] = k;
    }
    let visible = visible
        .into_iter()
        .filter(|&(_, j)| new_index[j] != usize::MAX)
        .map(|(i, j)| (i, new_index[j]))
        .collect();
    let gcps = gcps.iter().map(|&j| new_index[j]).collect();
    let points = keep.iter().map(|&j| points[j]).collect();
    Block {
        camera,
        poses,
        points,
        visible,
        gcps,
    }
}

/// One noise realisation, started as a pipeline would be: f 2 % long, no distortion, centred
/// principal point; poses with GNSS/IMU-like scatter (0.3°, 0.3 m); points triangulated from
/// those poses through the initial camera; GCPs at their surveyed coordinates.
fn realisation(b: &Block, seed: u64) -> BundleProblem {
    let mut rng = SeededRng::new(seed);
    let observations: Vec<Observation> = b
        .visible
        .iter()
        .map(|&(i, j)| {
            let sigma = if b.gcps.contains(&j) {
                MARKER_PX
            } else {
                SIGMA_PX
            };
            let px = project_world(&b.camera, &b.poses[i], &b.points[j]).expect("visible");
            Observation {
                image: i,
                point: j,
                pixel: px + Vector2::new(rng.normal(), rng.normal()) * sigma,
                sigma_px: sigma,
            }
        })
        .collect();
    let point_priors: Vec<PointPrior> = b
        .gcps
        .iter()
        .map(|&j| common::surveyed(j, &b.points[j], 0.01, 0.015, &mut rng))
        .collect();
    let start =
        BrownCamera::new(b.camera.width, b.camera.height, b.camera.f * 1.02).expect("camera");
    let poses: Vec<Pose> = b
        .poses
        .iter()
        .map(|p| {
            p.retract(&Vector6::from_fn(|k, _| {
                (if k < 3 { 0.005 } else { 0.3 }) * rng.normal()
            }))
        })
        .collect();
    let mut views: Vec<Vec<(Pose, Vector3<f64>)>> = vec![Vec::new(); b.points.len()];
    for o in &observations {
        if let Ok(ray) = start.unproject(&o.pixel) {
            views[o.point].push((poses[o.image], ray));
        }
    }
    // Triangulated points a pipeline would keep: in front of every camera seeing them, rays at
    // least 3° apart. The others are dropped with their observations.
    let mut index = vec![usize::MAX; b.points.len()];
    let mut points = Vec::new();
    for j in 0..b.points.len() {
        let position = match point_priors.iter().find(|p| p.point == j) {
            Some(p) => p.position,
            None => {
                let Ok(x) = triangulate_dlt(&views[j]) else {
                    continue;
                };
                let in_front = views[j]
                    .iter()
                    .all(|(pose, _)| pose.transform_point(&x).z > 0.0);
                let widest = views[j]
                    .iter()
                    .flat_map(|(p, _)| views[j].iter().map(move |(q, _)| (p, q)))
                    .map(|(p, q)| (x - p.center()).angle(&(x - q.center())))
                    .fold(0.0f64, f64::max);
                if !in_front || widest < 3f64.to_radians() {
                    continue;
                }
                x
            }
        };
        index[j] = points.len();
        points.push(BundlePoint {
            position,
            fixed: false,
        });
    }
    let observations: Vec<Observation> = observations
        .into_iter()
        .filter(|o| index[o.point] != usize::MAX)
        .map(|o| Observation {
            point: index[o.point],
            ..o
        })
        .collect();
    let point_priors: Vec<PointPrior> = point_priors
        .into_iter()
        .map(|p| PointPrior {
            point: index[p.point],
            ..p
        })
        .collect();
    BundleProblem {
        groups: vec![CameraGroup::with_free(Camera::Brown(start), &FREE).expect("group")],
        images: poses
            .into_iter()
            .map(|pose| BundleImage {
                pose,
                group: 0,
                fixed: false,
            })
            .collect(),
        points,
        observations,
        center_priors: Vec::new(),
        prior_offsets: Vec::new(),
        point_priors,
        scale_bars: Vec::new(),
    }
}

#[test]
fn self_calibration_recovers_synth_cameras_with_honest_standard_deviations() {
    let b = block();
    assert!(b.visible.len() > 10_000, "{} observations", b.visible.len());
    let options = BundleOptions {
        function_tolerance: 1e-12,
        parameter_tolerance: 1e-12,
        ..BundleOptions::default()
    };
    let runs = RUNS;
    let (mut f, mut k1) = (Vec::new(), Vec::new());
    let (mut var_f, mut var_k1) = (0.0, 0.0);
    let (mut worst_f, mut worst_k1) = (0.0f64, 0.0f64);
    for run in 0..runs {
        let mut p = realisation(&b, 500 + run);
        let report = solve(&mut p, &options).expect("solve");
        let (fe, k1e) = (common::intrinsic(&p, F), common::intrinsic(&p, K1));
        if run < 3 || (fe / b.camera.f - 1.0).abs() > 1e-3 {
            println!(
                "run {run}: f {fe:.3} (true {:.3}), k1 {k1e:.5} (true {:.5}), {report:?}",
                b.camera.f, b.camera.k1
            );
        }
        worst_f = worst_f.max((fe / b.camera.f - 1.0).abs());
        worst_k1 = worst_k1.max((k1e / b.camera.k1 - 1.0).abs());
        let prec = precision(&p, CovarianceScale::Prior).expect("precision");
        var_f += prec.intrinsic_std(0, F).expect("f free").powi(2) / runs as f64;
        var_k1 += prec.intrinsic_std(0, K1).expect("k1 free").powi(2) / runs as f64;
        f.push(fe);
        k1.push(k1e);
    }
    let (ratio_f, ratio_k1) = (
        common::spread(&f) / var_f.sqrt(),
        common::spread(&k1) / var_k1.sqrt(),
    );
    println!(
        "{} images, {} observations: worst |Δf|/f {:.5} %, worst |Δk1|/k1 {:.3} %; \
         spread / reported σ over {runs} runs: f {ratio_f:.3} (σ {:.3} px), k1 {ratio_k1:.3} (σ {:.2e})",
        b.poses.len(),
        b.visible.len(),
        100.0 * worst_f,
        100.0 * worst_k1,
        var_f.sqrt(),
        var_k1.sqrt()
    );
    assert!(worst_f < 1e-3, "f off by {:.4} %", 100.0 * worst_f);
    assert!(worst_k1 < 0.05, "k1 off by {:.2} %", 100.0 * worst_k1);
    assert!(
        (0.8..1.2).contains(&ratio_f),
        "f: spread / σ = {ratio_f:.3}"
    );
    assert!(
        (0.8..1.2).contains(&ratio_k1),
        "k1: spread / σ = {ratio_k1:.3}"
    );
}
