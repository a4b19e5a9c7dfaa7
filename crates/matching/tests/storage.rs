//! The binary feature and match files: exact round trip, and damaged files are errors that name
//! the file.

use timesift_core::{Descriptors, Keypoint};
use timesift_matching::Match;
use timesift_matching::storage::{read_features, read_matches, write_features, write_matches};

fn keypoints(n: usize) -> Vec<Keypoint> {
    (0..n)
        .map(|i| Keypoint {
            x: 10.25 + i as f64,
            y: 3.5 * i as f64,
            scale: 1.6 + 0.01 * i as f64,
            orientation: 0.1 * i as f64,
            response: 0.02 * i as f32,
            octave: i as i16 - 1,
        })
        .collect()
}

#[test]
fn files_round_trip_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let kp = keypoints(7);
    let float = Descriptors::Float {
        dim: 3,
        data: (0..21).map(|i| i as f32 / 7.0).collect(),
    };
    let binary = Descriptors::Binary {
        bytes: 5,
        data: (0..35).map(|i| (i * 37 % 256) as u8).collect(),
    };
    for (name, d) in [("f.feat", &float), ("b.feat", &binary)] {
        let path = dir.path().join("features").join(name);
        write_features(&path, &kp, d).unwrap();
        let (k2, d2) = read_features(&path).unwrap();
        assert_eq!(k2, kp);
        assert_eq!(&d2, d);
    }
    let matches = vec![
        Match {
            query: 1,
            train: 4,
            distance: 0.25,
        },
        Match {
            query: 6,
            train: 0,
            distance: 17.0,
        },
    ];
    let path = dir.path().join("m.match");
    write_matches(&path, &matches).unwrap();
    assert_eq!(read_matches(&path).unwrap(), matches);
    // Empty sets too.
    write_matches(&path, &[]).unwrap();
    assert!(read_matches(&path).unwrap().is_empty());
}

#[test]
fn truncated_corrupt_or_foreign_files_are_named_errors() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("img.feat");
    let d = Descriptors::Float {
        dim: 4,
        data: vec![0.5; 40],
    };
    write_features(&path, &keypoints(10), &d).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    // Truncated.
    std::fs::write(&path, &bytes[..bytes.len() - 30]).unwrap();
    let err = read_features(&path).unwrap_err().to_string();
    assert!(
        err.contains("img.feat") && err.contains("truncated or damaged"),
        "{err}"
    );
    // One flipped byte.
    let mut flipped = bytes.clone();
    flipped[100] ^= 0x40;
    std::fs::write(&path, &flipped).unwrap();
    let err = read_features(&path).unwrap_err().to_string();
    assert!(err.contains("checksum"), "{err}");
    // Too short for a header.
    std::fs::write(&path, b"TSFEAT").unwrap();
    let err = read_features(&path).unwrap_err().to_string();
    assert!(err.contains("too short"), "{err}");
    // A match file read as features.
    write_matches(&path, &[]).unwrap();
    let err = read_features(&path).unwrap_err().to_string();
    assert!(err.contains("not a timesift feature file"), "{err}");
    // Missing file.
    let err = read_matches(&dir.path().join("none.match"))
        .unwrap_err()
        .to_string();
    assert!(err.contains("none.match"), "{err}");
}
