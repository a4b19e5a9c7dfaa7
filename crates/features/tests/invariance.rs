//! Orientation and descriptors under rotation, scale and brightness changes of a real photo.

mod common;

use common::{Grey, angle_error, lund_photo, repeated, warp};
use timesift_core::{Descriptors, Keypoint};
use timesift_features::ldb::hamming;
use timesift_features::{
    DetectorOptions, FeatureExtractor, Features, GreyImage, LdbExtractor, SiftExtractor,
    SiftNormalization, detect,
};

fn grey(image: &Grey) -> GreyImage<'_> {
    GreyImage::new(image.width, image.height, &image.data).unwrap()
}

#[test]
fn orientation_follows_a_rotated_image() {
    let a = lund_photo();
    let rotation = 30f64.to_radians();
    let (b, t) = warp(&a, rotation, 1.0, 1.0, 0.0);
    let options = DetectorOptions::default();
    let ka = detect(&grey(&a), None, &options).unwrap();
    let kb = detect(&grey(&b), None, &options).unwrap();
    // Pairs at the same place and scale: compare each orientation of a with the closest
    // orientation of b at that place.
    let mut errors = Vec::new();
    for (i, found) in repeated(&ka, &kb, &t, 0.5).iter().enumerate() {
        let Some(j) = *found else { continue };
        let at_place: Vec<&Keypoint> = kb
            .iter()
            .filter(|k| k.x == kb[j].x && k.y == kb[j].y && k.scale == kb[j].scale)
            .collect();
        let error = at_place
            .iter()
            .map(|k| angle_error(k.orientation, ka[i].orientation + rotation))
            .fold(f64::INFINITY, f64::min);
        errors.push(error.to_degrees());
    }
    errors.sort_by(f64::total_cmp);
    let within = errors.iter().filter(|&&e| e <= 2.0).count() as f64 / errors.len() as f64;
    let median = errors[errors.len() / 2];
    println!(
        "{} of {} keypoints repeated after a 30° rotation; orientation error median {median:.3}°, \
         {:.1} % within 2°, 90th percentile {:.2}°",
        errors.len(),
        ka.len(),
        100.0 * within,
        errors[errors.len() * 9 / 10]
    );
    assert!(errors.len() > 500);
    assert!(median < 0.5, "median orientation error {median}°");
    assert!(within >= 0.9, "{:.1} % within 2°", 100.0 * within);
}

/// Share of repeatable keypoints of `fa` whose nearest descriptor in `fb` lies at the warped
/// position (within 3 px).
fn correct_nearest_neighbours(
    fa: &Features,
    fb: &Features,
    t: &common::Similarity,
) -> (usize, f64) {
    let pairs = repeated(&fa.keypoints, &fb.keypoints, t, 1.5);
    let distance = |i: usize, j: usize| -> f64 {
        match (&fa.descriptors, &fb.descriptors) {
            (Descriptors::Float { dim, data: a }, Descriptors::Float { data: b, .. }) => a
                [i * dim..(i + 1) * dim]
                .iter()
                .zip(&b[j * dim..(j + 1) * dim])
                .map(|(x, y)| ((x - y) * (x - y)) as f64)
                .sum(),
            (Descriptors::Binary { bytes, data: a }, Descriptors::Binary { data: b, .. }) => {
                hamming(
                    &a[i * bytes..(i + 1) * bytes],
                    &b[j * bytes..(j + 1) * bytes],
                ) as f64
            }
            _ => unreachable!("same extractor on both images"),
        }
    };
    let (mut repeatable, mut correct) = (0, 0);
    for (i, found) in pairs.iter().enumerate() {
        if found.is_none() {
            continue;
        }
        repeatable += 1;
        let nearest = (0..fb.keypoints.len())
            .min_by(|&p, &q| distance(i, p).total_cmp(&distance(i, q)))
            .unwrap();
        let (x, y) = t.apply(fa.keypoints[i].x, fa.keypoints[i].y);
        let kb = &fb.keypoints[nearest];
        if (kb.x - x).hypot(kb.y - y) <= 3.0 {
            correct += 1;
        }
    }
    (repeatable, correct as f64 / repeatable as f64)
}

#[test]
fn descriptors_match_under_rotation_scale_and_brightness() {
    let a = lund_photo();
    // 35° rotation, 1.3× scale, darker with less contrast.
    let (b, t) = warp(&a, 35f64.to_radians(), 1.3, 0.7, 0.1);
    let extractors: [(&str, Box<dyn FeatureExtractor>); 3] = [
        ("sift", Box::new(SiftExtractor::default())),
        (
            "rootsift",
            Box::new(SiftExtractor {
                normalization: SiftNormalization::Root,
                ..SiftExtractor::default()
            }),
        ),
        ("ldb", Box::new(LdbExtractor::default())),
    ];
    for (name, extractor) in extractors {
        let fa = extractor.extract(&grey(&a), None).unwrap();
        let fb = extractor.extract(&grey(&b), None).unwrap();
        assert_eq!(extractor.name(), name);
        let (repeatable, share) = correct_nearest_neighbours(&fa, &fb, &t);
        println!(
            "{name}: {} and {} keypoints, {repeatable} repeatable, {:.1} % correct nearest neighbours",
            fa.keypoints.len(),
            fb.keypoints.len(),
            100.0 * share
        );
        assert!(repeatable > 500);
        assert!(share >= 0.9, "{name}: {:.1} % correct", 100.0 * share);
    }
}
