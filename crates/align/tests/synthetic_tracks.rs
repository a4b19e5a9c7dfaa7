//! Structure from motion and georeferencing on synthetic tracks (exact projections of known
//! points through known cameras, optionally with pixel noise): exact recovery up to a similarity
//! without noise, error bounds with noise, GNSS georeferencing to the priors' accuracy, and clear
//! errors on degenerate input.

use nalgebra::{UnitQuaternion, Vector2, Vector3};
use proptest::prelude::*;
use timesift_align::{
    AlignError, Block, CentrePrior, ChunkAlignment, Datum, GeoreferenceInput, Georeferenced,
    GroundPoint, GuidedMatch, GuidedQuery, Independent, ManualStablePoints, Mapper, Marker,
    NaturalPoint, OfferedTiePoint, OffsetPrior, ProgressiveMerge, Reconstruction, ScatterWeighing,
    SfmImage, SfmInput, SfmOptions, SingleBlock, StableMatch, StableMatcher, StableSearch,
    StableTiePoints, Strategy, georeference, ground_point_residuals, reconstruct,
};
use timesift_core::{
    BrownCamera, Camera, CameraModel, FeatureIndex, ImageId, Pose, SeededRng, Track, TrackElement,
    project_world,
};
use timesift_geometry::similarity::{TransformKind, umeyama};

/// A nadir block: a grid of cameras 20 m above points with 3 m of relief.
struct Scene {
    input: SfmInput,
    poses: Vec<Pose>,
    points: Vec<Vector3<f64>>,
}

fn camera() -> Camera {
    let mut c = BrownCamera::new(1000, 800, 900.0).unwrap();
    c.k1 = -0.05;
    c.k2 = 0.02;
    c.cx = 3.0;
    c.cy = -2.0;
    Camera::Brown(c)
}

fn scene(seed: u64, noise_px: f64, n_points: usize) -> Scene {
    scene_with_motion(seed, noise_px, n_points, &|_, _| Vector3::zeros())
}

/// The nadir block, where image `i` sees point `x` displaced by `motion(i, x)`.
fn scene_with_motion(
    seed: u64,
    noise_px: f64,
    n_points: usize,
    motion: &dyn Fn(usize, &Vector3<f64>) -> Vector3<f64>,
) -> Scene {
    let mut rng = SeededRng::new(seed);
    let mut poses = Vec::new();
    for row in 0..4 {
        for col in 0..5 {
            let centre = Vector3::new(
                -6.0 + 3.0 * col as f64 + rng.uniform_range(-0.3, 0.3),
                -4.5 + 3.0 * row as f64 + rng.uniform_range(-0.3, 0.3),
                20.0 + rng.uniform_range(-0.5, 0.5),
            );
            // Looking down (camera z = −world z), x east, y south, with a few degrees of tilt.
            let down = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
            let tilt = UnitQuaternion::from_euler_angles(
                rng.uniform_range(-0.05, 0.05),
                rng.uniform_range(-0.05, 0.05),
                rng.uniform_range(-0.1, 0.1),
            );
            poses.push(Pose::from_rotation_and_center(tilt * down, &centre));
        }
    }
    let points: Vec<Vector3<f64>> = (0..n_points)
        .map(|_| {
            Vector3::new(
                rng.uniform_range(-14.0, 14.0),
                rng.uniform_range(-12.0, 12.0),
                rng.uniform_range(0.0, 3.0),
            )
        })
        .collect();
    observe(poses, points, noise_px, &mut rng, motion)
}

/// The scene whose images (at `poses`, through [`camera`]) see `points`, image `i` seeing point
/// `x` displaced by `motion(i, x)`, with `noise_px` of pixel noise; the start camera is off.
fn observe(
    poses: Vec<Pose>,
    points: Vec<Vector3<f64>>,
    noise_px: f64,
    rng: &mut SeededRng,
    motion: &dyn Fn(usize, &Vector3<f64>) -> Vector3<f64>,
) -> Scene {
    let camera = camera();
    let mut keypoints: Vec<Vec<Vector2<f64>>> = vec![Vec::new(); poses.len()];
    let mut tracks = Vec::new();
    for x in &points {
        let mut elements = Vec::new();
        for (i, pose) in poses.iter().enumerate() {
            let Ok(u) = project_world(&camera, pose, &(x + motion(i, x))) else {
                continue;
            };
            if u.x < 0.0 || u.y < 0.0 || u.x > 1000.0 || u.y > 800.0 {
                continue;
            }
            let noisy = u + Vector2::new(rng.normal(), rng.normal()) * noise_px;
            elements.push(TrackElement {
                image: ImageId::from(i),
                feature: FeatureIndex::from(keypoints[i].len()),
            });
            keypoints[i].push(noisy);
        }
        tracks.push(Track { elements });
    }
    let mut start = BrownCamera::new(1000, 800, 850.0).unwrap();
    start.cx = 0.0;
    Scene {
        input: one_camera_input(Camera::Brown(start), keypoints, tracks),
        poses,
        points,
    }
}

/// An input whose images all share one camera.
fn one_camera_input(
    camera: Camera,
    keypoints: Vec<Vec<Vector2<f64>>>,
    tracks: Vec<Track>,
) -> SfmInput {
    SfmInput {
        cameras: vec![camera],
        images: keypoints
            .into_iter()
            .map(|keypoints| SfmImage {
                group: 0,
                keypoints,
            })
            .collect(),
        tracks,
        focal: Vec::new(),
    }
}

/// Largest camera-centre error after the best similarity onto the truth, and the median point
/// error, both in metres (the median: points seen twice at the block's edge under a small angle
/// are legitimately uncertain in depth).
fn errors_after_similarity(rec: &Reconstruction, scene: &Scene) -> (f64, f64) {
    let oriented: Vec<usize> = (0..scene.poses.len())
        .filter(|&i| rec.poses[i].is_some())
        .collect();
    let ours: Vec<_> = oriented
        .iter()
        .map(|&i| rec.poses[i].unwrap().center())
        .collect();
    let truth: Vec<_> = oriented.iter().map(|&i| scene.poses[i].center()).collect();
    let t = umeyama(&ours, &truth, None, TransformKind::Similarity).unwrap();
    let centre = ours
        .iter()
        .zip(&truth)
        .map(|(a, b)| (t.apply(a) - b).norm())
        .fold(0.0, f64::max);
    let mut errors: Vec<f64> = rec
        .points
        .iter()
        .map(|p| (t.apply(&p.position) - scene.points[p.track]).norm())
        .collect();
    errors.sort_by(f64::total_cmp);
    (centre, errors[errors.len() / 2])
}

#[test]
fn noise_free_tracks_are_recovered_exactly_up_to_a_similarity() {
    let s = scene(1, 0.0, 1500);
    let components = reconstruct(&s.input, &SfmOptions::default()).unwrap();
    assert_eq!(components.len(), 1);
    let rec = &components[0];
    assert_eq!(rec.num_oriented(), 20);
    let rms = rec.rms_px(&s.input);
    let (centre, point_median) = errors_after_similarity(rec, &s);
    println!("rms {rms:.2e} px, centre {centre:.2e} m, points {point_median:.2e} m");
    assert!(rms < 1e-4, "rms {rms}");
    assert!(
        centre < 1e-4 && point_median < 1e-4,
        "{centre} {point_median}"
    );
    // Self-calibration found the true intrinsics from a 6 % wrong focal length.
    let mut p = [0.0; 11];
    rec.cameras[0].params(&mut p);
    let mut t = [0.0; 11];
    camera().params(&mut t);
    assert!((p[0] - t[0]).abs() < 1e-3, "f {} vs {}", p[0], t[0]);
}

#[test]
fn noisy_tracks_stay_within_error_bounds() {
    let s = scene(2, 0.5, 1500);
    let components = reconstruct(&s.input, &SfmOptions::default()).unwrap();
    let rec = &components[0];
    assert_eq!(rec.num_oriented(), 20);
    let rms = rec.rms_px(&s.input);
    let (centre, point_median) = errors_after_similarity(rec, &s);
    println!("rms {rms:.3} px, centre {centre:.4} m, points {point_median:.4} m");
    // 0.5 px noise per axis: about 0.7 px per observation, less the fitted share.
    assert!(rms > 0.4 && rms < 0.75, "rms {rms}");
    // A pixel is 2.2 cm on the ground; a point seen from 3 m apart at 20 m has a depth precision
    // of (20 / 3) · (20 / 900) · 0.5 ≈ 7 cm from two views, better from more.
    assert!(
        centre < 0.03 && point_median < 0.1,
        "{centre} {point_median}"
    );
}

#[test]
fn gnss_priors_place_the_block_in_the_world() {
    let s = scene(3, 0.3, 1200);
    let components = reconstruct(&s.input, &SfmOptions::default()).unwrap();
    let mut rng = SeededRng::new(9);
    // 5 cm priors; one gross outlier that the similarity RANSAC must reject.
    let mut priors: Vec<CentrePrior> = s
        .poses
        .iter()
        .enumerate()
        .map(|(i, p)| CentrePrior {
            image: i,
            position: p.center() + Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.05,
            sigma_xy: 0.05,
            sigma_z: 0.05,
            offset: None,
        })
        .collect();
    priors[7].position.x += 30.0;
    let geo = GeoreferenceInput {
        centre_priors: priors,
        prior_offsets: Vec::new(),
        points: Vec::new(),
        marker_sigma_px: 0.5,
        rigid_sets: Vec::new(),
        surface_heights: Vec::new(),
        reference_dem: None,
    };
    let placed = georeference(&s.input, components, &geo, &SfmOptions::default()).unwrap();
    assert_eq!(placed.datum, Datum::Gnss);
    assert_eq!(placed.diagnostics.rejected_priors, 1);
    let errors: Vec<f64> = (0..s.poses.len())
        .map(|i| (placed.reconstruction.poses[i].unwrap().center() - s.poses[i].center()).norm())
        .collect();
    let worst = errors.iter().copied().fold(0.0, f64::max);
    let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
    println!(
        "centre errors: rms {rms:.4} m, worst {worst:.4} m; {:.3} px",
        placed.rms_px
    );
    // Each centre is pulled towards its own 5 cm prior; the datum from 19 priors is good to
    // about a centimetre.
    assert!(
        rms < 0.05 && worst < 0.12,
        "centre errors rms {rms}, worst {worst}"
    );
}

#[test]
fn no_tracks_is_a_clear_error() {
    let mut s = scene(4, 0.0, 300);
    s.input.tracks.clear();
    let err = reconstruct(&s.input, &SfmOptions::default()).unwrap_err();
    assert!(matches!(err, AlignError::NoInitialPair { .. }), "{err}");
    assert!(err.to_string().contains("no initial pair"), "{err}");
}

#[test]
fn bad_input_names_what_is_wrong() {
    let mut s = scene(5, 0.0, 200);
    s.input.tracks[3].elements[0].feature = FeatureIndex(1_000_000);
    let err = reconstruct(&s.input, &SfmOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("track 3") && err.contains("does not exist"),
        "{err}"
    );
    let mut s = scene(5, 0.0, 200);
    s.input.images[2].group = 4;
    let err = reconstruct(&s.input, &SfmOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("image 2") && err.contains("camera group 4"),
        "{err}"
    );
    let options = SfmOptions {
        max_reprojection_px: -1.0,
        ..SfmOptions::default()
    };
    let err = reconstruct(&scene(5, 0.0, 200).input, &options)
        .unwrap_err()
        .to_string();
    assert!(err.contains("max_reprojection_px"), "{err}");
}

/// A survey flown twice over the same waypoints (a few centimetres apart): the most connected
/// pairs are the repeated waypoints, with no baseline to start from. With only a few pairs
/// evaluated at a time, the reconstruction must go on to pairs with a baseline, not give up or
/// start from a degenerate pair, and recover the block exactly.
#[test]
fn repeated_waypoints_do_not_start_the_reconstruction() {
    let first = scene(11, 0.0, 900);
    let n = first.poses.len();
    let mut poses = first.poses.clone();
    poses.extend(first.poses.iter().map(|p| {
        let centre = p.center() + Vector3::new(0.02, -0.01, 0.01);
        Pose::from_rotation_and_center(p.rotation, &centre)
    }));
    let twice = observe(
        poses,
        first.points.clone(),
        0.0,
        &mut SeededRng::new(12),
        &|_, _| Vector3::zeros(),
    );
    let options = SfmOptions {
        init_max_trials: 5,
        ..SfmOptions::default()
    };
    let components = reconstruct(&twice.input, &options).unwrap();
    assert_eq!(components[0].num_oriented(), 2 * n);
    let (centre, point_median) = errors_after_similarity(&components[0], &twice);
    assert!(
        centre < 1e-3 && point_median < 1e-3,
        "{centre} {point_median}"
    );
}

/// A rotation about the centre (no baseline) cannot start a reconstruction.
#[test]
fn pure_rotation_has_no_initial_pair() {
    let camera = camera();
    let mut rng = SeededRng::new(6);
    let poses: Vec<Pose> = (0..3)
        .map(|k| {
            Pose::from_rotation_and_center(
                UnitQuaternion::from_euler_angles(0.0, 0.05 * k as f64, 0.0),
                &Vector3::zeros(),
            )
        })
        .collect();
    let mut keypoints = vec![Vec::new(); 3];
    let mut tracks = Vec::new();
    for _ in 0..400 {
        let x = Vector3::new(
            rng.uniform_range(-5.0, 5.0),
            rng.uniform_range(-4.0, 4.0),
            rng.uniform_range(8.0, 12.0),
        );
        let mut elements = Vec::new();
        for (i, pose) in poses.iter().enumerate() {
            let u = project_world(&camera, pose, &x).unwrap();
            elements.push(TrackElement {
                image: ImageId::from(i),
                feature: FeatureIndex::from(keypoints[i].len()),
            });
            keypoints[i].push(u);
        }
        tracks.push(Track { elements });
    }
    let input = one_camera_input(camera, keypoints, tracks);
    let err = reconstruct(&input, &SfmOptions::default()).unwrap_err();
    assert!(matches!(err, AlignError::NoInitialPair { .. }), "{err}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(8))]
    /// Any seeded noise-free block is recovered up to a similarity.
    #[test]
    fn any_noise_free_block_is_recovered(seed in 0u64..1_000_000) {
        let s = scene(seed, 0.0, 900);
        let components = reconstruct(&s.input, &SfmOptions::default()).unwrap();
        prop_assert_eq!(components[0].num_oriented(), 20);
        let (centre, point_median) = errors_after_similarity(&components[0], &s);
        prop_assert!(centre < 1e-3 && point_median < 1e-3, "{} {}", centre, point_median);
    }
}

/// Two "epochs" of the nadir block (its first two and last two rows) with exact GNSS priors,
/// the second epoch's biased by `bias`; every prior claims 1.5 m, as a receiver with such a bias
/// honestly would.
fn two_epoch_block(s: &Scene, bias: Vector3<f64>) -> Block {
    let epoch_of: Vec<usize> = (0..s.poses.len()).map(|i| usize::from(i >= 10)).collect();
    let centre_priors = s
        .poses
        .iter()
        .enumerate()
        .map(|(i, p)| CentrePrior {
            image: i,
            position: p.center()
                + if epoch_of[i] == 1 {
                    bias
                } else {
                    Vector3::zeros()
                },
            sigma_xy: 1.5,
            sigma_z: 1.5,
            offset: None,
        })
        .collect();
    // Each epoch's rigid motion is asked for: the covariance runs in every block test.
    let rigid_sets = (0..2)
        .map(|e| (0..epoch_of.len()).filter(|&i| epoch_of[i] == e).collect())
        .collect();
    Block {
        sfm: s.input.clone(),
        ground: GeoreferenceInput {
            centre_priors,
            prior_offsets: Vec::new(),
            points: Vec::new(),
            marker_sigma_px: 0.5,
            rigid_sets,
            surface_heights: Vec::new(),
            reference_dem: None,
        },
        epoch_of,
        epoch_names: vec!["first".into(), "second".into()],
        reference: 0,
        stable_ground: None,
        natural_points: Vec::new(),
    }
}

/// [`two_epoch_block`] with `bias` on the second epoch's priors, which carry a GNSS offset
/// (σ 3 m), and the first epoch's priors at 5 cm (RTK).
fn block_with_an_offset_for_the_second_epoch(s: &Scene, bias: Vector3<f64>) -> Block {
    let mut block = two_epoch_block(s, bias);
    block.ground.prior_offsets = vec![OffsetPrior {
        name: "second".into(),
        sigma_xy: 3.0,
        sigma_z: 3.0,
    }];
    for p in &mut block.ground.centre_priors {
        p.offset = (block.epoch_of[p.image] == 1).then_some(0);
        if p.offset.is_none() {
            (p.sigma_xy, p.sigma_z) = (0.05, 0.05);
        }
    }
    block
}

/// Mean camera-centre error (estimated − true) of the images of one epoch.
fn mean_offset(g: &Georeferenced, s: &Scene, block: &Block, epoch: usize) -> Vector3<f64> {
    let images: Vec<usize> = (0..s.poses.len())
        .filter(|&i| block.epoch_of[i] == epoch)
        .collect();
    images
        .iter()
        .map(|&i| g.reconstruction.poses[i].unwrap().center() - s.poses[i].center())
        .sum::<Vector3<f64>>()
        / images.len() as f64
}

/// Largest camera-centre residual after one similarity of all cameras onto the truth: how far
/// the epochs are from forming one rigid block.
fn rigid_misfit(g: &Georeferenced, s: &Scene) -> f64 {
    let ours: Vec<_> = (0..s.poses.len())
        .map(|i| g.reconstruction.poses[i].unwrap().center())
        .collect();
    let truth: Vec<_> = s.poses.iter().map(|p| p.center()).collect();
    let t = umeyama(&ours, &truth, None, TransformKind::Similarity).unwrap();
    ours.iter()
        .zip(&truth)
        .map(|(a, b)| (t.apply(a) - b).norm())
        .fold(0.0, f64::max)
}

#[test]
fn strategies_differ_as_the_papers_say_on_biased_gnss() {
    let s = scene(7, 0.3, 1500);
    let bias = Vector3::new(2.0, 0.0, 0.0);
    let block = two_epoch_block(&s, bias);
    let options = SfmOptions::default();
    // Independent: the second epoch follows its biased priors; the epochs do not fit together.
    let independent = Independent.orient(&block, &options).unwrap();
    assert_eq!(independent.reconstruction.num_oriented(), 20);
    let off = mean_offset(&independent, &s, &block, 1);
    let misfit = rigid_misfit(&independent, &s);
    println!("independent: second epoch off by {off:?}, rigid misfit {misfit:.3} m");
    assert!((off - bias).norm() < 0.1, "{off:?}");
    assert!(mean_offset(&independent, &s, &block, 0).norm() < 0.05);
    assert!(misfit > 0.5, "{misfit}");
    // Chunk: the second epoch is mapped onto the reference through shared tie points.
    let chunk = ChunkAlignment.orient(&block, &options).unwrap();
    assert_eq!(chunk.reconstruction.num_oriented(), 20);
    let off = mean_offset(&chunk, &s, &block, 1);
    let misfit = rigid_misfit(&chunk, &s);
    println!("chunk: second epoch off by {off:?}, rigid misfit {misfit:.3} m");
    assert!(off.norm() < 0.1 && misfit < 0.1, "{off:?} {misfit}");
    // One block: the epochs share one geometry whatever the priors say; the datum is a
    // compromise between the two epochs' priors.
    let single = SingleBlock::default().orient(&block, &options).unwrap();
    let misfit = rigid_misfit(&single, &s);
    let (a, b) = (
        mean_offset(&single, &s, &block, 0),
        mean_offset(&single, &s, &block, 1),
    );
    println!("timesift: epochs off by {a:?} and {b:?}, rigid misfit {misfit:.4} m");
    assert!(misfit < 0.05, "{misfit}");
    assert!(
        (a.x + b.x) / 2.0 > 0.5 && (a.x + b.x) / 2.0 < 1.5,
        "{a:?} {b:?}"
    );
    // Progressive merge: epochs alone, then one block like timesift's.
    let msfm = ProgressiveMerge.orient(&block, &options).unwrap();
    assert_eq!(msfm.reconstruction.num_oriented(), 20);
    let misfit = rigid_misfit(&msfm, &s);
    println!("msfm: rigid misfit {misfit:.4} m");
    assert!(misfit < 0.05, "{misfit}");
    // Stable tie points: the second epoch, placed first by its biased priors, ends on the
    // reference epoch's tie points (here matched by their common track, standing in for
    // descriptors), with its own geometry adjusted.
    let matcher = SameTrack::new(&block.sfm);
    let stp = StableTiePoints { matcher: &matcher }
        .orient(&block, &options)
        .unwrap();
    assert_eq!(stp.reconstruction.num_oriented(), 20);
    let off = mean_offset(&stp, &s, &block, 1);
    let misfit = rigid_misfit(&stp, &s);
    println!("stp: second epoch off by {off:?}, rigid misfit {misfit:.4} m");
    assert!(off.norm() < 0.1 && misfit < 0.1, "{off:?} {misfit}");
    // Strategy names and lookup: each name parses to its method, whose strategy is that one.
    for method in timesift_align::Method::ALL {
        let parsed: timesift_align::Method = method.name().parse().unwrap();
        assert_eq!(parsed, method);
        assert_eq!(timesift_align::strategy(method, &matcher).method(), method);
    }
    let unknown = "magic".parse::<timesift_align::Method>().unwrap_err();
    assert!(
        unknown.to_string().contains("`magic`") && unknown.to_string().contains("timesift"),
        "{unknown}"
    );
}

/// `count` of the scene's points spread over the block (the farthest-point order from its
/// centre), as natural points measured by hand in every image that sees them, with `noise_px`
/// of marker noise.
fn natural_points(s: &Scene, count: usize, noise_px: f64, seed: u64) -> Vec<NaturalPoint> {
    let camera = camera();
    let mut rng = SeededRng::new(seed);
    let mut chosen: Vec<usize> = Vec::new();
    while chosen.len() < count {
        let next = (0..s.points.len())
            .filter(|k| !chosen.contains(k))
            .max_by(|&a, &b| {
                let spread = |k: usize| {
                    let p = s.points[k].xy();
                    chosen
                        .iter()
                        .map(|&c| (s.points[c].xy() - p).norm())
                        .fold(12.0 - p.norm(), f64::min)
                };
                spread(a).total_cmp(&spread(b))
            })
            .unwrap();
        chosen.push(next);
    }
    chosen
        .iter()
        .enumerate()
        .map(|(n, &k)| NaturalPoint {
            name: format!("rock {n}"),
            stability: None,
            markers: s
                .poses
                .iter()
                .enumerate()
                .filter_map(|(image, pose)| {
                    let u = project_world(&camera, pose, &s.points[k]).ok()?;
                    (u.x > 0.0 && u.y > 0.0 && u.x < 1000.0 && u.y < 800.0).then(|| Marker {
                        image,
                        pixel: u + Vector2::new(rng.normal(), rng.normal()) * noise_px,
                    })
                })
                .collect(),
        })
        .collect()
}

/// The manual method: the second epoch's GNSS is biased by 2 m and the epochs share no tie
/// point, yet six natural points measured by hand in both put it on the reference within a
/// small fraction of the bias; without enough such points it fails naming what is missing.
#[test]
fn natural_points_measured_by_hand_control_the_later_epochs() {
    let s = scene(7, 0.3, 1500);
    let bias = Vector3::new(2.0, 0.0, 0.0);
    let mut block = two_epoch_block(&s, bias);
    // No tie point joins the epochs: only the hand-measured points can.
    let epoch_of = block.epoch_of.clone();
    for track in &mut block.sfm.tracks {
        let first = epoch_of[track.elements[0].image.index()];
        track
            .elements
            .retain(|e| epoch_of[e.image.index()] == first);
    }
    block.sfm.tracks.retain(|t| t.elements.len() >= 2);
    let options = SfmOptions::default();
    let missing = ManualStablePoints.orient(&block, &options).unwrap_err();
    assert!(
        missing.to_string().contains("stable_points.csv"),
        "{missing}"
    );
    block.natural_points = natural_points(&s, 6, 0.5, 3);
    for p in &block.natural_points {
        let (a, b) = p
            .markers
            .iter()
            .partition::<Vec<&Marker>, _>(|m| epoch_of[m.image] == 0);
        assert!(
            a.len() >= 4 && b.len() >= 2,
            "{}: {} + {}",
            p.name,
            a.len(),
            b.len()
        );
    }
    let manual = ManualStablePoints.orient(&block, &options).unwrap();
    assert_eq!(manual.reconstruction.num_oriented(), 20);
    let off = mean_offset(&manual, &s, &block, 1);
    let reference = mean_offset(&manual, &s, &block, 0);
    let misfit = rigid_misfit(&manual, &s);
    println!(
        "manual: reference off by {reference:?}, second epoch off by {off:?}, rigid misfit {misfit:.4} m"
    );
    assert!(reference.norm() < 0.05, "{reference:?}");
    assert!(off.norm() < 0.1 && misfit < 0.1, "{off:?} {misfit}");
    // Independent, on the same block, follows the bias.
    let independent = Independent.orient(&block, &options).unwrap();
    assert!((mean_offset(&independent, &s, &block, 1) - bias).norm() < 0.1);
    // Points measured in too few reference images cannot control anything.
    let mut sparse = block.clone();
    for p in &mut sparse.natural_points {
        let mut in_reference = 0;
        p.markers.retain(|m| {
            in_reference += usize::from(epoch_of[m.image] == 0);
            epoch_of[m.image] == 1 || in_reference <= 3
        });
    }
    let few = ManualStablePoints.orient(&sparse, &options).unwrap_err();
    let message = few.to_string();
    assert!(
        message.contains("\"first\"") && message.contains("0 of 6 natural stable points"),
        "{message}"
    );
}

/// One block with a GNSS offset for the biased epoch: the offset takes the bias (within three of
/// its reported σ), the reference epoch's unbiased priors keep the datum, and nothing is dragged
/// — where the plain single block above ends half-way between the epochs' priors. (The reference
/// epoch flew RTK, 5 cm: with two strips of 1.5 m priors alone, a vertical bias of one strip is
/// as well explained by a roll of the block about the strips' axis.)
#[test]
fn a_gnss_offset_per_epoch_takes_the_bias_in_one_block() {
    let s = scene(7, 0.3, 1500);
    let bias = Vector3::new(2.0, -1.0, 1.5);
    let block = block_with_an_offset_for_the_second_epoch(&s, bias);
    let single = SingleBlock::default()
        .orient(&block, &SfmOptions::default())
        .unwrap();
    assert_eq!(single.reconstruction.num_oriented(), 20);
    let offset = &single.gnss_offsets[0];
    let std = offset.std.expect("offset precision");
    println!(
        "offset {:?} ± {std:?} from {} priors",
        offset.value, offset.priors
    );
    assert_eq!((offset.name.as_str(), offset.priors), ("second", 10));
    for k in 0..3 {
        assert!(
            (offset.value[k] - bias[k]).abs() < 3.0 * std[k] + 1e-3,
            "axis {k}: {} ± {} for {}",
            offset.value[k],
            std[k],
            bias[k]
        );
    }
    // Exact 5 cm priors place the block to centimetres; the bias no longer adds to it.
    let (a, b) = (
        mean_offset(&single, &s, &block, 0),
        mean_offset(&single, &s, &block, 1),
    );
    println!("epochs off by {a:?} and {b:?}");
    assert!(a.norm() < 0.03 && (a - b).norm() < 0.03, "{a:?} {b:?}");
    assert!(rigid_misfit(&single, &s) < 0.05);
}

/// The options with the global mapper.
fn global_mapper() -> SfmOptions {
    SfmOptions {
        mapper: Mapper::Global,
        ..SfmOptions::default()
    }
}

/// Noise-free tracks and exact priors: the global mapper orients every image, exactly where it
/// was, and says it did (no fall-back).
#[test]
fn the_global_mapper_recovers_noise_free_tracks_exactly() {
    let s = scene(11, 0.0, 1500);
    let block = two_epoch_block(&s, Vector3::zeros());
    let g = SingleBlock::default()
        .orient(&block, &global_mapper())
        .unwrap();
    assert_eq!(g.diagnostics.mapper, Mapper::Global);
    assert_eq!(g.reconstruction.num_oriented(), 20);
    for (ours, truth) in g.reconstruction.poses.iter().zip(&s.poses) {
        let ours = ours.unwrap();
        assert!((ours.center() - truth.center()).norm() < 1e-4);
        assert!((ours.rotation.inverse() * truth.rotation).angle() < 1e-6);
    }
}

/// The per-epoch GNSS bias of `a_gnss_offset_per_epoch_takes_the_bias_in_one_block`, oriented
/// by the global and by the incremental mapper: the same block within the noise (centres within
/// a centimetre of each other, the offsets within their σ).
#[test]
fn the_global_and_the_incremental_mapper_agree_within_the_noise() {
    let s = scene(7, 0.3, 1500);
    let bias = Vector3::new(2.0, -1.0, 1.5);
    let block = block_with_an_offset_for_the_second_epoch(&s, bias);
    let global = SingleBlock::default()
        .orient(&block, &global_mapper())
        .unwrap();
    let incremental = SingleBlock::default()
        .orient(&block, &SfmOptions::default())
        .unwrap();
    assert_eq!(global.diagnostics.mapper, Mapper::Global);
    assert_eq!(incremental.diagnostics.mapper, Mapper::Incremental);
    assert_eq!(global.reconstruction.num_oriented(), 20);
    let largest = global
        .reconstruction
        .poses
        .iter()
        .zip(&incremental.reconstruction.poses)
        .map(|(a, b)| (a.unwrap().center() - b.unwrap().center()).norm())
        .fold(0.0, f64::max);
    println!("centres differ by at most {largest} m");
    assert!(largest < 0.01);
    let (a, b) = (&global.gnss_offsets[0], &incremental.gnss_offsets[0]);
    let std = b.std.expect("offset precision");
    for k in 0..3 {
        assert!(
            (a.value[k] - b.value[k]).abs() < std[k],
            "axis {k}: {a:?} {b:?}"
        );
    }
    assert!(rigid_misfit(&global, &s) < 0.05);
}

/// Without priors the global mapper cannot place the centres: it falls back to the incremental
/// mapper, says so, and orients the block all the same.
#[test]
fn without_priors_the_global_mapper_falls_back_to_the_incremental_one() {
    let s = scene(7, 0.3, 1500);
    let mut block = two_epoch_block(&s, Vector3::zeros());
    block.ground.centre_priors.clear();
    let g = SingleBlock::default()
        .orient(&block, &global_mapper())
        .unwrap();
    assert_eq!(g.diagnostics.mapper, Mapper::Incremental);
    assert_eq!(g.reconstruction.num_oriented(), 20);
}

/// Two flights with GNSS scattered by 0.2 m within each, stated at 3 m, control points marked
/// in the first: by default only the first flight's priors are weighed by their scatter, and
/// the second keeps its stated σ; with `ScatterWeighing::All` both are.
#[test]
fn only_the_controlled_flight_is_weighed_by_its_scatter() {
    let s = scene(7, 0.3, 1500);
    let mut rng = SeededRng::new(11);
    let mut block = two_epoch_block(&s, Vector3::zeros());
    let biases = [Vector3::new(0.5, -0.3, 1.0), Vector3::new(2.0, -1.0, 1.5)];
    block.ground.prior_offsets = ["first", "second"]
        .iter()
        .map(|name| OffsetPrior {
            name: (*name).into(),
            sigma_xy: 3.0,
            sigma_z: 3.0,
        })
        .collect();
    for p in &mut block.ground.centre_priors {
        let e = block.epoch_of[p.image];
        let noise = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.2;
        p.position = s.poses[p.image].center() + biases[e] + noise;
        (p.sigma_xy, p.sigma_z, p.offset) = (3.0, 3.0, Some(e));
    }
    let cam = camera();
    block.ground.points = s
        .points
        .iter()
        .enumerate()
        .map(|(k, x)| GroundPoint {
            name: format!("GCP{k}"),
            position: *x,
            sigma_xy: 0.01,
            sigma_z: 0.01,
            check: false,
            markers: (0..10)
                .filter_map(|image| {
                    let pixel = project_world(&cam, &s.poses[image], x).ok()?;
                    let inside =
                        (0.0..1000.0).contains(&pixel.x) && (0.0..800.0).contains(&pixel.y);
                    inside.then_some(Marker { image, pixel })
                })
                .collect(),
            marker_sigma_px: None,
        })
        .filter(|p| p.markers.len() >= 3)
        .take(4)
        .collect();
    assert_eq!(block.ground.points.len(), 4);
    let flags = |weighing: ScatterWeighing| {
        let options = SfmOptions {
            scatter_weighing: weighing,
            ..SfmOptions::default()
        };
        let g = SingleBlock::default().orient(&block, &options).unwrap();
        assert_eq!(g.gnss_offsets.len(), 2);
        g.gnss_offsets
            .iter()
            .map(|o| {
                let noise = o.within_flight_sigma.expect("ten priors: a scatter");
                assert!(noise[0] < 1.0 && noise[1] < 1.0, "{noise:?}");
                (o.scatter_weighs_priors, o.prior_sigma(3.0, 3.0))
            })
            .collect::<Vec<_>>()
    };
    let controlled = flags(ScatterWeighing::Controlled);
    println!("controlled: {controlled:?}");
    assert!(controlled[0].0 && controlled[0].1.1 < 1.0);
    assert_eq!(controlled[1], (false, (3.0, 3.0)));
    let all = flags(ScatterWeighing::All);
    println!("all: {all:?}");
    assert!(all.iter().all(|(weighs, sigma)| *weighs && sigma.1 < 1.0));
}

/// The descriptor matching of `stp` replaced by the truth of the synthetic tracks: two offered
/// points are a pair when their observations belong to one track and they lie within the search
/// radius.
struct SameTrack {
    track_of: std::collections::HashMap<TrackElement, usize>,
}

impl SameTrack {
    fn new(input: &SfmInput) -> Self {
        let mut track_of = std::collections::HashMap::new();
        for (t, track) in input.tracks.iter().enumerate() {
            for e in &track.elements {
                track_of.insert(*e, t);
            }
        }
        SameTrack { track_of }
    }
}

impl StableMatcher for SameTrack {
    fn stable_pairs(
        &self,
        reference: &[OfferedTiePoint<'_>],
        other: &[OfferedTiePoint<'_>],
        search: &StableSearch,
    ) -> Result<Vec<StableMatch>, String> {
        let by_track: std::collections::HashMap<usize, usize> = reference
            .iter()
            .enumerate()
            .filter_map(|(k, p)| Some((*self.track_of.get(p.observations.first()?)?, k)))
            .collect();
        Ok(other
            .iter()
            .enumerate()
            .filter_map(|(k, p)| {
                let t = self.track_of.get(p.observations.first()?)?;
                let r = *by_track.get(t)?;
                let d = reference[r].position - p.position;
                (d.xy().norm() <= search.radius).then_some(StableMatch {
                    reference: r,
                    other: k,
                    score: 0.1,
                })
            })
            .collect())
    }

    /// The candidate of the query point's own scene track, if offered.
    fn guided_matches(
        &self,
        queries: &[GuidedQuery<'_>],
    ) -> Result<Vec<Option<GuidedMatch>>, String> {
        Ok(queries
            .iter()
            .map(|q| {
                let t = self.track_of.get(q.observations.first()?)?;
                q.candidates
                    .iter()
                    .find(|&&feature| {
                        let e = TrackElement {
                            image: q.image,
                            feature,
                        };
                        self.track_of.get(&e) == Some(t)
                    })
                    .map(|&feature| GuidedMatch {
                        feature,
                        distance: 0.1,
                    })
            })
            .collect())
    }
}

/// How many epochs observe a point.
fn epoch_count(block: &Block, p: &timesift_align::SparsePoint) -> usize {
    p.observations
        .iter()
        .map(|e| block.epoch_of[e.image.index()])
        .collect::<std::collections::BTreeSet<usize>>()
        .len()
}

/// Tie points on a surface that moved between the epochs (a slide 4 m in radius around
/// (4, 0), 6 cm ≈ 2.7 px eastwards in the second epoch) are split by epoch; the stable ones keep
/// tying the epochs.
#[test]
fn tie_points_on_a_moved_surface_stop_tying_the_epochs() {
    let from_centre = |x: &Vector3<f64>| (x.xy() - Vector2::new(4.0, 0.0)).norm();
    let moved = |x: &Vector3<f64>| from_centre(x) < 4.0;
    let s = scene_with_motion(11, 0.3, 1500, &|i, x| {
        if i >= 10 && moved(x) {
            Vector3::new(0.06, 0.0, 0.0)
        } else {
            Vector3::zeros()
        }
    });
    let block = two_epoch_block(&s, Vector3::zeros());
    // Inter-epoch points on the slide and off it (a metre of margin).
    let ties = |g: &Georeferenced| {
        let (mut on, mut off) = (0, 0);
        for p in &g.reconstruction.points {
            let epochs = epoch_count(&block, p);
            if epochs == 2 && from_centre(&p.position) < 3.0 {
                on += 1;
            } else if epochs == 2 && from_centre(&p.position) > 5.0 {
                off += 1;
            }
        }
        (on, off)
    };
    let kept = SfmOptions {
        moved_point_factor: f64::INFINITY,
        ..SfmOptions::default()
    };
    let strained = SingleBlock::default().orient(&block, &kept).unwrap();
    let (on_before, off_before) = ties(&strained);
    let relaxed = SingleBlock::default()
        .orient(&block, &SfmOptions::default())
        .unwrap();
    let (on, off) = ties(&relaxed);
    println!(
        "kept: RMS {:.3} px, ties on the slide {on_before}, off {off_before}; \
         split: RMS {:.3} px, ties on {on}, off {off}",
        strained.rms_px, relaxed.rms_px
    );
    assert_eq!(relaxed.reconstruction.num_oriented(), 20);
    assert!(
        on_before > 30,
        "the moved surface must tie the epochs at first"
    );
    assert!(on * 20 <= on_before, "{on} of {on_before} moved ties left");
    assert_eq!(strained.diagnostics.moved_ties_split, 0);
    assert!(
        relaxed.diagnostics.moved_ties_split >= on_before,
        "{}",
        relaxed.diagnostics.moved_ties_split
    );
    assert!(
        off * 10 >= off_before * 9,
        "{off} of {off_before} stable ties left"
    );
    // 0.3 px per axis: an RMS of 0.3·√2 = 0.42 px once nothing strains the block.
    assert!(relaxed.rms_px < 0.45, "{}", relaxed.rms_px);
    assert!(strained.rms_px > relaxed.rms_px);
}

/// Ground that changed by less than the moved-point test sees (a disc 4 m in radius around
/// (4, 0) lowered by 10 cm in the second epoch: at most ~1 px in these images) still ties the
/// epochs, and the block gives its points one height, hiding the change. With the stable ground
/// given (everything but the disc and a metre around it), only ties on it join the epochs: the
/// second epoch's points on the disc are its own, and their heights show the change.
#[test]
fn only_ties_on_stable_ground_join_the_epochs_when_it_is_given() {
    const LOWERING: f64 = 0.1;
    let from_centre = |x: &Vector3<f64>| (x.xy() - Vector2::new(4.0, 0.0)).norm();
    let s = scene_with_motion(13, 0.3, 1500, &|i, x| {
        if i >= 10 && from_centre(x) < 4.0 {
            Vector3::new(0.0, 0.0, -LOWERING)
        } else {
            Vector3::zeros()
        }
    });
    let all = two_epoch_block(&s, Vector3::zeros());
    let stable = timesift_align::StableGround::rasterise([-20.0, -20.0], 0.1, 400, 400, |x, y| {
        (Vector2::new(x, y) - Vector2::new(4.0, 0.0)).norm() > 5.0
    })
    .unwrap();
    let stable_only = Block {
        stable_ground: Some(stable),
        ..all.clone()
    };
    let epochs_of = |p: &timesift_align::SparsePoint| {
        p.observations
            .iter()
            .map(|e| all.epoch_of[e.image.index()])
            .collect::<std::collections::BTreeSet<usize>>()
    };
    // Inter-epoch ties on the disc and off the unstable ring; and the mean height error of the
    // second epoch's own points on the disc.
    let summary = |g: &Georeferenced| {
        let (mut on, mut off) = (0, 0);
        let mut second = Vec::new();
        for p in &g.reconstruction.points {
            let epochs = epochs_of(p);
            let truth = s.points[p.track];
            if epochs.len() == 2 && from_centre(&truth) < 3.5 {
                on += 1;
            } else if epochs.len() == 2 && from_centre(&truth) > 5.5 {
                off += 1;
            } else if epochs.len() == 1 && epochs.contains(&1) && from_centre(&truth) < 3.5 {
                second.push(p.position.z - truth.z);
            }
        }
        let mean = (!second.is_empty()).then(|| second.iter().sum::<f64>() / second.len() as f64);
        (on, off, second.len(), mean)
    };
    let options = SfmOptions::default();
    let before = SingleBlock::default().orient(&all, &options).unwrap();
    let after = SingleBlock::default()
        .orient(&stable_only, &options)
        .unwrap();
    let (on_before, off_before, _, _) = summary(&before);
    let (on, off, own, lowered) = summary(&after);
    println!(
        "all ties: {on_before} on the disc, {off_before} off, {} split as moved; stable only: \
         {on} on, {off} off, {} split off stable ground, {own} second-epoch points on the disc \
         lowered by {lowered:?} m",
        before.diagnostics.moved_ties_split, after.diagnostics.unstable_ties_split
    );
    assert_eq!(before.diagnostics.unstable_ties_split, 0);
    assert!(
        on_before > 50,
        "the lowered disc must tie the epochs at first: {on_before}"
    );
    assert_eq!(on, 0, "inter-epoch ties left on the disc");
    assert!(after.diagnostics.unstable_ties_split >= on_before);
    assert!(
        off * 10 >= off_before * 9,
        "{off} of {off_before} stable ties left"
    );
    assert_eq!(after.reconstruction.num_oriented(), 20);
    let lowered = lowered.expect("the second epoch keeps its points on the disc");
    assert!(
        own >= on_before / 2,
        "{own} second-epoch points on the disc"
    );
    assert!(
        (lowered + LOWERING).abs() < 0.3 * LOWERING,
        "second epoch's disc lowered by {lowered:.3} m, truly {LOWERING} m"
    );
    assert!(after.rms_px < 0.45, "{}", after.rms_px);
}

/// A noisy camera group among quiet ones (scanned film among digital images: here the second
/// "epoch", 8 of 20 images, with 1.2 px of noise against 0.3 px) is judged by its own noise: the
/// bound pooled over the block (4 σ of mostly quiet errors, 1.9 px here) would cut a fifth of
/// its good observations; its own bound keeps nearly all.
#[test]
fn a_noisy_camera_group_keeps_the_observations_its_own_noise_allows() {
    const NOISY_PX: f64 = 1.2;
    let s = scene(17, 0.3, 1500);
    let mut block = two_epoch_block(&s, Vector3::zeros());
    let noisy = |i: usize| i >= 12;
    let mut rng = SeededRng::new(5);
    block.sfm.cameras.push(block.sfm.cameras[0].clone());
    for (_, image) in block
        .sfm
        .images
        .iter_mut()
        .enumerate()
        .filter(|(i, _)| noisy(*i))
    {
        image.group = 1;
        for k in &mut image.keypoints {
            // 0.3² + extra² = 1.2².
            let extra = (NOISY_PX * NOISY_PX - 0.09).sqrt();
            *k += Vector2::new(rng.normal(), rng.normal()) * extra;
        }
    }
    let g = SingleBlock::default()
        .orient(&block, &SfmOptions::default())
        .unwrap();
    assert_eq!(g.reconstruction.num_oriented(), 20);
    // Observations of the noisy images kept against those the tracks offer on oriented points.
    let (mut kept, mut offered) = (0usize, 0usize);
    let keeps: std::collections::HashSet<(usize, usize)> = g
        .reconstruction
        .points
        .iter()
        .flat_map(|p| {
            p.observations
                .iter()
                .map(move |e| (p.track, e.image.index()))
        })
        .collect();
    for p in &g.reconstruction.points {
        for e in &block.sfm.tracks[p.track].elements {
            if noisy(e.image.index()) {
                offered += 1;
                kept += usize::from(keeps.contains(&(p.track, e.image.index())));
            }
        }
    }
    let share = kept as f64 / offered as f64;
    println!(
        "bounds {:?} px (pooled {:?}), σ {:?} px; noisy group keeps {kept} of {offered} ({share:.3})",
        g.group_bound_px, g.observation_bound_px, g.group_sigma_px
    );
    // Residuals are smaller than the noise (the points fit some of it): σ of the residuals
    // within 0.8–1.1 of the noise.
    let sigma = g.group_sigma_px[1].unwrap();
    assert!(
        (0.8 * NOISY_PX..1.1 * NOISY_PX).contains(&sigma),
        "noisy group σ {sigma} px"
    );
    assert!(g.group_sigma_px[0].unwrap() < 0.4);
    assert!(g.group_bound_px[1] > 3.0 * g.group_bound_px[0]);
    assert!(
        share > 0.97,
        "noisy group keeps {share:.3} of its observations"
    );
}

/// `stp`'s stable control points are tie points of the later epoch: their observations weigh
/// with that epoch's own reprojection noise, so the accuracy the user states for hand-placed
/// markers (here 0.5 px, then a sloppy 5 px) does not change the result.
#[test]
fn stable_tie_points_weigh_with_the_epochs_own_noise_not_the_marker_accuracy() {
    let s = scene(7, 0.3, 1500);
    let matcher = SameTrack::new(&s.input);
    let options = SfmOptions::default();
    let centres = |marker_sigma_px: f64| {
        let mut block = two_epoch_block(&s, Vector3::new(2.0, 0.0, 0.0));
        block.ground.marker_sigma_px = marker_sigma_px;
        let g = StableTiePoints { matcher: &matcher }
            .orient(&block, &options)
            .unwrap();
        (0..s.poses.len())
            .map(|i| g.reconstruction.poses[i].unwrap().center())
            .collect::<Vec<_>>()
    };
    let (tight, sloppy) = (centres(0.5), centres(5.0));
    let largest = tight
        .iter()
        .zip(&sloppy)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    println!("largest camera-centre change between marker σ 0.5 and 5 px: {largest:.2e} m");
    assert!(largest < 1e-9, "{largest}");
}

/// Without stable areas, the regional change detection finds the lowered disc of the test above
/// from the block's own ties: intersected in each epoch apart, the disc's ties differ by a part of
/// the 10 cm that no single point shows but their mean does. Its ties stop tying the epochs, and
/// the second epoch's own points show the change, where the plain block gives the disc one
/// height between the epochs'.
#[test]
fn regional_change_detection_finds_a_lowered_disc_without_stable_areas() {
    const LOWERING: f64 = 0.1;
    let from_centre = |x: &Vector3<f64>| (x.xy() - Vector2::new(4.0, 0.0)).norm();
    let s = scene_with_motion(13, 0.3, 1500, &|i, x| {
        if i >= 10 && from_centre(x) < 4.0 {
            Vector3::new(0.0, 0.0, -LOWERING)
        } else {
            Vector3::zeros()
        }
    });
    let block = two_epoch_block(&s, Vector3::zeros());
    let epochs = |p: &timesift_align::SparsePoint| {
        p.observations
            .iter()
            .map(|e| block.epoch_of[e.image.index()])
            .collect::<std::collections::BTreeSet<usize>>()
    };
    // The disc's change as the block shows it (mean height error of the disc's points the
    // second epoch sees minus that of those the first sees: 0 where ties give both one height),
    // and the inter-epoch ties left on the disc and off it.
    let summary = |g: &Georeferenced| {
        let (mut on, mut off) = (0, 0);
        let mut error = [Vec::new(), Vec::new()];
        for p in &g.reconstruction.points {
            let truth = s.points[p.track];
            let e = epochs(p);
            if e.len() == 2 && from_centre(&truth) < 3.5 {
                on += 1;
            } else if e.len() == 2 && from_centre(&truth) > 5.5 {
                off += 1;
            }
            if from_centre(&truth) < 3.5 {
                for k in &e {
                    error[*k].push(p.position.z - truth.z);
                }
            }
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        (on, off, mean(&error[1]) - mean(&error[0]))
    };
    let plain = SingleBlock::default()
        .orient(&block, &SfmOptions::default())
        .unwrap();
    let options = SfmOptions {
        change_detection: timesift_align::ChangeDetection::Regional,
        ..SfmOptions::default()
    };
    let detected = SingleBlock::default().orient(&block, &options).unwrap();
    let (on_plain, off_plain, flattened) = summary(&plain);
    let (on, off, lowered) = summary(&detected);
    println!(
        "plain block: {on_plain} ties on the disc, {off_plain} off, disc lowered by \
         {flattened:.4} m between the epochs; regional detection: {} regions changed, {} ties split, {on} on the \
         disc, {off} off, disc lowered by {lowered:.4} m (truly {LOWERING} m)",
        detected.diagnostics.changed_regions, detected.diagnostics.unstable_ties_split
    );
    assert!(on_plain > 50 && plain.diagnostics.changed_regions == 0);
    assert!(
        flattened.abs() < 0.8 * LOWERING,
        "the plain block was expected to flatten the change: {flattened}"
    );
    assert!(detected.diagnostics.changed_regions > 0);
    assert!(
        on * 5 <= on_plain,
        "{on} of {on_plain} ties left on the disc"
    );
    assert!(
        off * 10 >= off_plain * 8,
        "{off} of {off_plain} ties left off the disc"
    );
    assert!(
        (lowered + LOWERING).abs() < 0.2 * LOWERING,
        "second epoch's disc lowered by {lowered:.4} m, truly {LOWERING} m"
    );
    assert_eq!(detected.reconstruction.num_oriented(), 20);
}

/// On ground that did not change the detection finds nothing and the block is the plain one.
#[test]
fn regional_change_detection_finds_nothing_where_nothing_changed() {
    let s = scene(7, 0.3, 1500);
    let block = two_epoch_block(&s, Vector3::zeros());
    let options = SfmOptions {
        change_detection: timesift_align::ChangeDetection::Regional,
        ..SfmOptions::default()
    };
    let detected = SingleBlock::default().orient(&block, &options).unwrap();
    println!(
        "{} regions changed, {} ties split",
        detected.diagnostics.changed_regions, detected.diagnostics.unstable_ties_split
    );
    assert_eq!(detected.diagnostics.changed_regions, 0);
    assert_eq!(detected.diagnostics.unstable_ties_split, 0);
}

/// Where the second epoch of [`slide_scene`] moved: a disc 4 m in radius around (4, 0).
fn on_slide(x: &Vector3<f64>) -> bool {
    (x.xy() - Vector2::new(4.0, 0.0)).norm() < 4.0
}

/// Two epochs whose second sees the slide ([`on_slide`]) moved 0.5 m east, with biased
/// priors, and whose tracks tie one stable point in twenty across them
/// ([`one_tie_in_twenty`]); and a matcher by the scene's own tracks, one per point: matching
/// by them is matching by the truth.
fn slide_scene() -> (Scene, Block, SameTrack) {
    let s = scene_with_motion(17, 0.3, 1500, &|i, x| {
        if i >= 10 && on_slide(x) {
            Vector3::new(0.5, 0.0, 0.0)
        } else {
            Vector3::zeros()
        }
    });
    let mut block = two_epoch_block(&s, Vector3::new(1.0, -0.5, 0.8));
    let matcher = SameTrack::new(&s.input);
    block.sfm.tracks = one_tie_in_twenty(&s, &block, &on_slide);
    (s, block, matcher)
}

/// Inter-epoch ties of `g` off the slide and on it, by the scene point they measure (the
/// block's frame is the biased priors', not the truth's).
fn slide_ties(g: &Georeferenced, s: &Scene, block: &Block, matcher: &SameTrack) -> (usize, usize) {
    let (mut stable, mut slide) = (0, 0);
    for p in &g.reconstruction.points {
        if epoch_count(block, p) < 2 {
            continue;
        }
        if on_slide(&s.points[matcher.track_of[&p.observations[0]]]) {
            slide += 1;
        } else {
            stable += 1;
        }
    }
    (stable, slide)
}

/// The scene's tracks as a feature matching that tied only one stable point in twenty across
/// the two epochs would give: the others a track per epoch.
fn one_tie_in_twenty(
    s: &Scene,
    block: &Block,
    on_slide: &dyn Fn(&Vector3<f64>) -> bool,
) -> Vec<Track> {
    let mut tracks = Vec::new();
    for (k, track) in s.input.tracks.iter().enumerate() {
        if k % 20 == 0 && !on_slide(&s.points[k]) {
            tracks.push(track.clone());
            continue;
        }
        for epoch in 0..2 {
            let elements: Vec<TrackElement> = track
                .elements
                .iter()
                .filter(|e| block.epoch_of[e.image.index()] == epoch)
                .copied()
                .collect();
            if elements.len() >= 2 {
                tracks.push(Track { elements });
            }
        }
    }
    tracks
}

/// Two epochs whose feature matching joined only one scene point in twenty across them (the
/// others are a track per epoch), and whose second epoch sees a slide (a disc 4 m in radius
/// around (4, 0)) moved 0.5 m east: the second look joins the stable points' two tracks into
/// inter-epoch ties, not the slide's (beyond the search radius), and the epochs then agree
/// better than on the few ties the matching found.
#[test]
fn a_second_look_joins_the_epochs_tie_points_of_one_stable_ground_point() {
    let (s, block, matcher) = slide_scene();
    let ties = |g: &Georeferenced| slide_ties(g, &s, &block, &matcher);
    let options = SfmOptions::default();
    let few = SingleBlock::default().orient(&block, &options).unwrap();
    let off = SingleBlock {
        matcher: Some(&matcher),
    }
    .orient(
        &block,
        &SfmOptions {
            join_epoch_ties: false,
            ..options.clone()
        },
    )
    .unwrap();
    let joined = SingleBlock {
        matcher: Some(&matcher),
    }
    .orient(
        &block,
        &SfmOptions {
            join_epoch_ties: true,
            ..options.clone()
        },
    )
    .unwrap();
    let (few_stable, few_slide) = ties(&few);
    let (stable, slide) = ties(&joined);
    println!(
        "matching alone: {few_stable} ties ({few_slide} on the slide), misfit {:.4} m; \
         second look: {} joined, {stable} ties ({slide} on the slide), misfit {:.4} m",
        rigid_misfit(&few, &s),
        joined.diagnostics.joined_ties,
        rigid_misfit(&joined, &s)
    );
    assert_eq!(
        off, few,
        "join_epoch_ties = false is the plain single block"
    );
    assert_eq!(off.diagnostics.joined_ties, 0);
    assert_eq!(few_slide, 0);
    // About 19 in 20 of the stable points seen in both epochs were left apart.
    assert!(
        joined.diagnostics.joined_ties >= 10 * few_stable,
        "{} joined",
        joined.diagnostics.joined_ties
    );
    assert!(
        stable >= 10 * few_stable,
        "{stable} ties against {few_stable}"
    );
    assert_eq!(slide, 0, "the slide moved beyond the search radius");
    assert!(rigid_misfit(&joined, &s) < rigid_misfit(&few, &s));
}

/// A check point clicked with the stated accuracy through the true cameras, so that its clicks
/// are all its residual holds: the σ `ground_point_residuals` reports from the markers alone is
/// the scatter of the residuals over many clickings, in every axis, and a point clicked in two
/// neighbouring images is looser in height than one clicked in every image that sees it.
#[test]
fn a_ground_point_s_markers_sigma_is_the_scatter_of_its_clicks() {
    let s = scene(3, 0.0, 10);
    let cam = camera();
    let rec = Reconstruction {
        cameras: vec![cam.clone()],
        poses: s.poses.iter().copied().map(Some).collect(),
        points: Vec::new(),
    };
    let point = Vector3::new(0.5, -0.5, 1.2);
    let seen: Vec<(usize, Vector2<f64>)> = (0..s.poses.len())
        .filter_map(|image| {
            let pixel = project_world(&cam, &s.poses[image], &point).ok()?;
            let inside = (0.0..1000.0).contains(&pixel.x) && (0.0..800.0).contains(&pixel.y);
            inside.then_some((image, pixel))
        })
        .collect();
    assert!(seen.len() >= 6, "{} images see the point", seen.len());
    let sigma_px = 0.5;
    let mut rng = SeededRng::new(5);
    let trials = 2000;
    let mut height_sigma = Vec::new();
    for images in [2, seen.len()] {
        let mut squares = Vector3::zeros();
        let mut reported = Vector3::zeros();
        for _ in 0..trials {
            let markers = seen[..images]
                .iter()
                .map(|&(image, pixel)| Marker {
                    image,
                    pixel: pixel + Vector2::new(rng.normal(), rng.normal()) * sigma_px,
                })
                .collect();
            let geo = GeoreferenceInput {
                centre_priors: Vec::new(),
                prior_offsets: Vec::new(),
                points: vec![GroundPoint {
                    name: "CHK1".into(),
                    position: point,
                    sigma_xy: 0.01,
                    sigma_z: 0.01,
                    check: true,
                    markers,
                    marker_sigma_px: None,
                }],
                marker_sigma_px: sigma_px,
                rigid_sets: Vec::new(),
                surface_heights: Vec::new(),
                reference_dem: None,
            };
            let residual = &ground_point_residuals(&s.input, &rec, &geo, &|_| true)[0];
            assert_eq!(residual.images, images);
            let d = residual.residual.expect("intersected");
            squares += d.component_mul(&d);
            reported += residual.markers_sigma.expect("a covariance");
        }
        let scatter = (squares / trials as f64).map(f64::sqrt);
        let reported = reported / trials as f64;
        println!("{images} images: scatter {scatter:?}, reported {reported:?}");
        for k in 0..3 {
            assert!(
                (scatter[k] / reported[k] - 1.0).abs() < 0.1,
                "axis {k}: scatter {} against reported {}",
                scatter[k],
                reported[k]
            );
        }
        height_sigma.push(reported.z);
    }
    assert!(
        height_sigma[0] > 2.0 * height_sigma[1],
        "two images {} m, all {} m",
        height_sigma[0],
        height_sigma[1]
    );
}

/// The same two epochs as the second look's test, tied by one scene point in twenty: projected
/// into the other epoch's images by the first block, the points find their own keypoints among
/// the few near their projection, and the epochs are tied by every stable point both see —
/// not by the slide, which moved beyond the search radius.
#[test]
fn a_guided_look_finds_each_point_near_its_projection_in_the_other_epoch() {
    let (s, block, matcher) = slide_scene();
    let ties = |g: &Georeferenced| slide_ties(g, &s, &block, &matcher);
    let options = SfmOptions::default();
    let few = SingleBlock::default().orient(&block, &options).unwrap();
    let guided = SingleBlock {
        matcher: Some(&matcher),
    }
    .orient(
        &block,
        &SfmOptions {
            guided_epoch_ties: true,
            ..options.clone()
        },
    )
    .unwrap();
    let (few_stable, _) = ties(&few);
    let (stable, slide) = ties(&guided);
    println!(
        "matching alone: {few_stable} ties, misfit {:.4} m; guided: {} found, {stable} ties \
         ({slide} on the slide), misfit {:.4} m",
        rigid_misfit(&few, &s),
        guided.diagnostics.guided_ties,
        rigid_misfit(&guided, &s)
    );
    assert_eq!(few.diagnostics.guided_ties, 0);
    assert!(
        guided.diagnostics.guided_ties >= 10 * few_stable,
        "{} found",
        guided.diagnostics.guided_ties
    );
    assert!(
        stable >= 10 * few_stable,
        "{stable} ties against {few_stable}"
    );
    assert_eq!(slide, 0, "the slide moved beyond the search radius");
    assert!(rigid_misfit(&guided, &s) < rigid_misfit(&few, &s));
}
