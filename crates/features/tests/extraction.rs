//! Extraction as a whole: errors on bad input, masks, the keypoint budget, identical results
//! whatever the memory budget or the thread count, and the text format.

mod common;

use common::lund_photo;
use timesift_core::Descriptors;
use timesift_features::text::{DescriptorKind, read, write};
use timesift_features::{
    DetectorOptions, FeatureError, FeatureExtractor, GreyImage, KeypointLimit, LdbExtractor, Mask,
    Orientation, SiftExtractor,
};

#[test]
fn bad_inputs_are_clear_errors() {
    let data = vec![0.5f32; 100];
    assert!(matches!(
        GreyImage::new(11, 10, &data),
        Err(FeatureError::BufferSize { got: 100, .. })
    ));
    let mut nan = data.clone();
    nan[23] = f32::NAN;
    nan[40] = f32::INFINITY;
    let err = GreyImage::new(10, 10, &nan).unwrap_err();
    assert!(matches!(
        err,
        FeatureError::NonFinitePixels {
            count: 2,
            col: 3,
            row: 2
        }
    ));
    assert!(err.to_string().contains("column 3, row 2"), "{err}");
    let tiny = GreyImage::new(10, 10, &data).unwrap();
    let err = SiftExtractor::default().extract(&tiny, None).unwrap_err();
    assert!(err.to_string().contains("too small"), "{err}");
    let photo = lund_photo();
    let image = GreyImage::new(photo.width, photo.height, &photo.data).unwrap();
    let small_mask = vec![1u8; 100];
    let mask = Mask::new(10, 10, &small_mask).unwrap();
    let err = SiftExtractor::default()
        .extract(&image, Some(&mask))
        .unwrap_err();
    assert!(err.to_string().contains("mask is 10 × 10"), "{err}");
    let bad = SiftExtractor {
        detector: DetectorOptions {
            edge_ratio: 0.5,
            ..DetectorOptions::default()
        },
        ..SiftExtractor::default()
    };
    let err = bad.extract(&image, None).unwrap_err();
    assert!(err.to_string().contains("edge_ratio"), "{err}");
}

#[test]
fn masked_areas_hold_no_keypoint_and_the_rest_is_unchanged() {
    let photo = lund_photo();
    let image = GreyImage::new(photo.width, photo.height, &photo.data).unwrap();
    // Exclude a frame of 100 px and the upper half, as for a scan's fiducial frame and the sky.
    let (w, h) = (photo.width, photo.height);
    let pixels: Vec<u8> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            u8::from(x >= 100 && x < w - 100 && y >= h / 2 && y < h - 100)
        })
        .collect();
    let mask = Mask::new(w, h, &pixels).unwrap();
    let extractor = SiftExtractor::default();
    let all = extractor.extract(&image, None).unwrap();
    let masked = extractor.extract(&image, Some(&mask)).unwrap();
    assert!(!masked.keypoints.is_empty());
    assert!(masked.keypoints.iter().all(|k| mask.allows(k.x, k.y)));
    let inside: Vec<_> = all
        .keypoints
        .iter()
        .filter(|k| mask.allows(k.x, k.y))
        .collect();
    assert_eq!(inside.len(), masked.keypoints.len());
    println!(
        "{} keypoints, {} inside the mask, {} with the mask",
        all.keypoints.len(),
        inside.len(),
        masked.keypoints.len()
    );
}

#[test]
fn the_budget_keeps_strong_keypoints_spread_over_the_image() {
    let photo = lund_photo();
    let image = GreyImage::new(photo.width, photo.height, &photo.data).unwrap();
    let all = SiftExtractor::default().extract(&image, None).unwrap();
    let limited = SiftExtractor {
        detector: DetectorOptions {
            limit: Some(KeypointLimit {
                spread: 1.0,
                ..KeypointLimit::spread(500)
            }),
            ..DetectorOptions::default()
        },
        ..SiftExtractor::default()
    }
    .extract(&image, None)
    .unwrap();
    assert_eq!(limited.keypoints.len(), 500);
    assert_eq!(limited.descriptors.len(), 500);
    // Every kept keypoint is one of the unlimited run, with the same descriptor.
    let (Descriptors::Float { data: da, .. }, Descriptors::Float { data: dl, .. }) =
        (&all.descriptors, &limited.descriptors)
    else {
        panic!("float descriptors")
    };
    for (i, k) in limited.keypoints.iter().enumerate() {
        let j = all
            .keypoints
            .iter()
            .position(|a| a == k)
            .expect("kept keypoint exists");
        assert_eq!(&da[j * 128..(j + 1) * 128], &dl[i * 128..(i + 1) * 128]);
    }
    // Spread: the 8 × 8 grid has keypoints in far more cells than the 500 strongest alone reach.
    let cells = |ks: &mut dyn Iterator<Item = (f64, f64)>| {
        let mut seen = std::collections::BTreeSet::new();
        for (x, y) in ks {
            seen.insert((
                (x / photo.width as f64 * 8.0) as usize,
                (y / photo.height as f64 * 8.0) as usize,
            ));
        }
        seen.len()
    };
    let mut strongest: Vec<_> = all.keypoints.clone();
    strongest.sort_by(|a, b| b.response.total_cmp(&a.response));
    let spread = cells(&mut limited.keypoints.iter().map(|k| (k.x, k.y)));
    let greedy = cells(&mut strongest[..500].iter().map(|k| (k.x, k.y)));
    println!("occupied cells of 64: spread {spread}, strongest-only {greedy}");
    assert!(spread > greedy);
}

#[test]
fn results_do_not_depend_on_memory_budget_or_threads() {
    let photo = lund_photo();
    let image = GreyImage::new(photo.width, photo.height, &photo.data).unwrap();
    let whole = LdbExtractor::default().extract(&image, None).unwrap();
    // 2 MiB forces the doubled octave into bands of 64 core rows, recomputed for description.
    let banded = LdbExtractor {
        detector: DetectorOptions {
            memory_budget: 2 << 20,
            ..DetectorOptions::default()
        },
    }
    .extract(&image, None)
    .unwrap();
    assert_same(&whole, &banded, "2 MiB memory budget");
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let single = pool.install(|| LdbExtractor::default().extract(&image, None).unwrap());
    assert_same(&whole, &single, "one thread");
    // Many more extrema (no contrast threshold) and odd layer counts: where a keypoint settles
    // across a band boundary, the order must not follow the bands.
    for layers in [1, 3] {
        let options = DetectorOptions {
            contrast_threshold: 0.0,
            layers_per_octave: layers,
            ..DetectorOptions::default()
        };
        let whole = LdbExtractor { detector: options }
            .extract(&image, None)
            .unwrap();
        let banded = LdbExtractor {
            detector: DetectorOptions {
                memory_budget: 1 << 20,
                ..options
            },
        }
        .extract(&image, None)
        .unwrap();
        assert_same(&whole, &banded, &format!("{layers} layers, 1 MiB budget"));
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap();
        let three = pool.install(|| {
            LdbExtractor {
                detector: DetectorOptions {
                    memory_budget: 4 << 20,
                    ..options
                },
            }
            .extract(&image, None)
            .unwrap()
        });
        assert_same(
            &whole,
            &three,
            &format!("{layers} layers, 3 threads, 4 MiB"),
        );
    }
}

/// Equality of two extractions, reported by the first difference rather than by two dumps.
fn assert_same(a: &timesift_features::Features, b: &timesift_features::Features, what: &str) {
    assert_eq!(
        a.keypoints.len(),
        b.keypoints.len(),
        "{what}: keypoint count"
    );
    if let Some(i) = (0..a.keypoints.len()).find(|&i| a.keypoints[i] != b.keypoints[i]) {
        panic!(
            "{what}: keypoint {i} differs: {:?} vs {:?}",
            a.keypoints[i], b.keypoints[i]
        );
    }
    if let (Descriptors::Binary { bytes, data: da }, Descriptors::Binary { data: db, .. }) =
        (&a.descriptors, &b.descriptors)
    {
        let differ: Vec<usize> = (0..a.keypoints.len())
            .filter(|&i| da[i * bytes..(i + 1) * bytes] != db[i * bytes..(i + 1) * bytes])
            .collect();
        for &i in differ.iter().take(5) {
            eprintln!("{what}: descriptor {i} differs ({:?})", a.keypoints[i]);
        }
        assert!(
            differ.is_empty(),
            "{what}: {} descriptors differ",
            differ.len()
        );
    }
    assert!(a.descriptors == b.descriptors, "{what}: descriptors differ");
}

#[test]
fn upright_keypoints_have_orientation_zero() {
    let photo = lund_photo();
    let image = GreyImage::new(photo.width, photo.height, &photo.data).unwrap();
    let upright = SiftExtractor {
        detector: DetectorOptions {
            orientation: Orientation::Upright,
            ..DetectorOptions::default()
        },
        ..SiftExtractor::default()
    }
    .extract(&image, None)
    .unwrap();
    assert!(!upright.keypoints.is_empty());
    assert!(upright.keypoints.iter().all(|k| k.orientation == 0.0));
}

#[test]
fn text_format_round_trips_and_reports_damage() {
    let photo = lund_photo();
    let image = GreyImage::new(photo.width, photo.height, &photo.data).unwrap();
    let dir = tempfile::tempdir().unwrap();
    for (extractor, kind) in [
        (
            Box::new(SiftExtractor::default()) as Box<dyn FeatureExtractor>,
            DescriptorKind::Float,
        ),
        (Box::new(LdbExtractor::default()), DescriptorKind::Binary),
    ] {
        let features = extractor.extract(&image, None).unwrap();
        let path = dir.path().join(format!("{}.txt", extractor.name()));
        write(&path, &features).unwrap();
        let back = read(&path, kind).unwrap();
        assert_eq!(back.descriptors, features.descriptors);
        for (a, b) in back.keypoints.iter().zip(&features.keypoints) {
            assert_eq!(
                (a.x, a.y, a.scale, a.orientation),
                (b.x, b.y, b.scale, b.orientation)
            );
        }
        // Truncated: the error names the file and says how many keypoints were found.
        let text = std::fs::read_to_string(&path).unwrap();
        let cut: String = text.lines().take(11).map(|l| format!("{l}\n")).collect();
        std::fs::write(&path, cut).unwrap();
        let err = read(&path, kind).unwrap_err().to_string();
        assert!(
            err.contains(&path.display().to_string()) && err.contains("after 10 keypoints"),
            "{err}"
        );
    }
    let path = dir.path().join("bad.txt");
    std::fs::write(&path, "1 2\n1 2 3 4 5 300\n").unwrap();
    let err = read(&path, DescriptorKind::Binary).unwrap_err().to_string();
    assert!(err.contains("bad.txt:2") && err.contains("`300`"), "{err}");
    // Crafted headers: an absurd descriptor length, a zero one, a huge count.
    std::fs::write(&path, "1 18446744073709551615\n1 2 3\n").unwrap();
    let err = read(&path, DescriptorKind::Float).unwrap_err().to_string();
    assert!(
        err.contains("bad.txt:1") && err.contains("not plausible"),
        "{err}"
    );
    std::fs::write(&path, "2 0\n1 2 3 4\n5 6 7 8\n").unwrap();
    let err = read(&path, DescriptorKind::Float).unwrap_err().to_string();
    assert!(err.contains("D is 0"), "{err}");
    std::fs::write(&path, "99999999999 1\n1 2 3 4 5\n").unwrap();
    let err = read(&path, DescriptorKind::Float).unwrap_err().to_string();
    assert!(err.contains("after 1 keypoints"), "{err}");
    std::fs::write(&path, "2 x\n").unwrap();
    let err = read(&path, DescriptorKind::Float).unwrap_err().to_string();
    assert!(err.contains("bad.txt:1"), "{err}");
}

#[test]
fn many_files_are_extracted_in_parallel_with_errors_per_image() {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/opensfm/lund/images");
    let paths = vec![
        dir.join("03.jpg"),
        dir.join("missing.jpg"),
        dir.join("04.jpg"),
    ];
    let results = std::sync::Mutex::new(Vec::new());
    let extractor = LdbExtractor::default();
    timesift_features::files::extract_files(&paths, &extractor, |i, path, result| {
        results
            .lock()
            .unwrap()
            .push((i, path.to_path_buf(), result.map(|f| f.keypoints.len())));
    });
    let mut results = results.into_inner().unwrap();
    results.sort_by_key(|r| r.0);
    assert_eq!(results.len(), 3);
    let alone = timesift_features::files::extract_file(&paths[0], &extractor).unwrap();
    assert_eq!(*results[0].2.as_ref().unwrap(), alone.keypoints.len());
    let err = results[1].2.as_ref().unwrap_err().to_string();
    assert!(err.contains("missing.jpg"), "{err}");
    assert!(*results[2].2.as_ref().unwrap() > 1000);
}
