//! A synthetic scene is a project the tool reads unchanged: `soil-pit` at the small scale,
//! rendered, then `timesift info` on it sees every epoch, image, control point, marker, GNSS
//! prior and scale bar the generator wrote, and the images are the camera's size.

use crate::common::timesift;
use timesift_synth::scenes::{Scale, build};
use timesift_synth::writer::{WriteOptions, write_scene};

#[test]
fn a_rendered_scene_is_a_project_timesift_reads() {
    let dir = tempfile::tempdir().expect("tempdir");
    let spec = build("soil-pit", Scale::Small, 1).expect("scene");
    let written = write_scene(&spec, dir.path(), &WriteOptions::default()).expect("write");
    let path = dir.path().to_str().expect("utf-8 path");
    let (ok, out, err) = timesift(&["info", path, "--json"]);
    assert!(ok, "{err}");
    let info: serde_json::Value = serde_json::from_str(&out).expect("json");
    assert_eq!(info["epochs"].as_array().map(Vec::len), Some(2));
    assert_eq!(
        info["images"].as_array().map(Vec::len),
        Some(written.images)
    );
    let inputs = &info["inputs"];
    assert_eq!(inputs["gcps"], spec.gcps.len());
    assert_eq!(inputs["checkpoints"], spec.checkpoints.len());
    assert_eq!(inputs["markers"], written.markers);
    assert_eq!(inputs["gnss"], written.images);
    assert_eq!(inputs["scale_bars"], 4);
    let first = dir.path().join("images/2025-05-20_1000/IMG_0001.jpg");
    let (w, h) = timesift_io::image::dimensions(&first).expect("image");
    assert_eq!(
        (w, h),
        (spec.epochs[0].camera.width, spec.epochs[0].camera.height)
    );
    // A textured image: neighbouring pixels differ almost everywhere.
    let grey = timesift_io::image::read_grey(&first).expect("image");
    let varied = grey
        .data
        .windows(2)
        .filter(|p| (p[0] - p[1]).abs() > 0.002)
        .count();
    assert!(
        varied > grey.data.len() / 3,
        "{varied} of {}",
        grey.data.len()
    );
}
