//! timesift used as a library from outside its workspace, with a part of one's own swapped in.
//!
//! A research group wants keypoints spread evenly over every image (SIFT bunches them on
//! texture) and writes its own [`FeatureExtractor`]: SIFT's keypoints thinned to the strongest
//! one per cell of a square grid. This program renders a synthetic two-epoch project with
//! `timesift-synth`, extracts its features with that extractor through
//! [`timesift::stages::extract_features`], runs timesift's matching and orientation on them, and
//! checks in the orientation result (`out/colmap/`) that every observation is one of the
//! extractor's keypoints and that no image has two observations in one grid cell, which SIFT
//! alone would give.
//!
//! Usage: `timesift-downstream-example <empty-dir>`; prints a summary, exits with an error if a
//! check fails.

use std::collections::{HashMap, HashSet};
use std::path::PathBuf;
use std::sync::Mutex;

use timesift::stages::{Stage, extract_features, run};
use timesift_core::{Descriptors, Keypoint};
use timesift_features::{FeatureError, FeatureExtractor, Features, GreyImage, Mask, SiftExtractor};

/// SIFT keypoints thinned to the largest-scale one per `cell × cell` pixels, remembering every
/// keypoint it returned.
struct EvenSift {
    sift: SiftExtractor,
    cell: f64,
    returned: Mutex<HashSet<(u32, u32)>>,
}

/// A keypoint position as exact bits, as the feature files store it (f32).
fn key(x: f64, y: f64) -> (u32, u32) {
    ((x as f32).to_bits(), (y as f32).to_bits())
}

impl FeatureExtractor for EvenSift {
    fn name(&self) -> &'static str {
        "even-sift"
    }

    fn extract(&self, image: &GreyImage, mask: Option<&Mask>) -> Result<Features, FeatureError> {
        let all = self.sift.extract(image, mask)?;
        let Descriptors::Float { dim, data } = &all.descriptors else {
            unreachable!("SIFT descriptors are floats");
        };
        let mut best: HashMap<(i64, i64), usize> = HashMap::new();
        for (k, p) in all.keypoints.iter().enumerate() {
            let cell = ((p.x / self.cell) as i64, (p.y / self.cell) as i64);
            let slot = best.entry(cell).or_insert(k);
            if p.scale > all.keypoints[*slot].scale {
                *slot = k;
            }
        }
        let mut kept: Vec<usize> = best.into_values().collect();
        kept.sort_unstable();
        let keypoints: Vec<Keypoint> = kept.iter().map(|&k| all.keypoints[k]).collect();
        let descriptors = Descriptors::Float {
            dim: *dim,
            data: kept
                .iter()
                .flat_map(|&k| data[k * dim..(k + 1) * dim].iter().copied())
                .collect(),
        };
        let mut returned = self.returned.lock().unwrap_or_else(|e| e.into_inner());
        returned.extend(keypoints.iter().map(|p| key(p.x, p.y)));
        Ok(Features {
            keypoints,
            descriptors,
        })
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::env::args_os()
        .nth(1)
        .map(PathBuf::from)
        .ok_or("usage: timesift-downstream-example <empty-dir>")?;
    let mut spec =
        timesift_synth::scenes::build("soil-pit", timesift_synth::scenes::Scale::Small, 1)?;
    // The first ten images of each epoch: enough for a block, quick enough for a test.
    spec.keep_first_images(10);
    timesift_synth::writer::write_scene(&spec, &dir, &Default::default())?;
    let project = timesift::Project::load(&dir)?;

    let extractor = EvenSift {
        sift: SiftExtractor::default(),
        cell: 24.0,
        returned: Mutex::new(HashSet::new()),
    };
    let extracted = extract_features(&project, &extractor)?;
    let returned = extractor
        .returned
        .into_inner()
        .unwrap_or_else(|e| e.into_inner());
    println!(
        "even-sift: {extracted} images, {} keypoints",
        returned.len()
    );
    for outcome in run(&project, Some(Stage::Match), Some(Stage::Align))? {
        println!("{}: {}", outcome.stage, outcome.summary);
    }

    let cameras = timesift_io::cameras_json::read_cameras_json(&dir.join("out/cameras.json"))?;
    let oriented = cameras.images.iter().filter(|i| i.pose.is_some()).count();
    let model = timesift_io::colmap::read_colmap_text(&dir.join("out/colmap"))?;
    let (mut observations, mut foreign, mut crowded) = (0usize, 0usize, 0usize);
    for image in model.images.values() {
        let mut cells = HashSet::new();
        for &(x, y, _) in &image.points2d {
            observations += 1;
            if !returned.contains(&key(x, y)) {
                foreign += 1;
            }
            if !cells.insert(((x / extractor.cell) as i64, (y / extractor.cell) as i64)) {
                crowded += 1;
            }
        }
    }
    println!(
        "orientation: {oriented} of {} images oriented, {observations} observations, {foreign} \
         not from even-sift, {crowded} in a grid cell already observed",
        project.images.len()
    );
    if oriented != project.images.len() || observations == 0 {
        return Err("not every image was oriented".into());
    }
    if foreign > 0 || crowded > 0 {
        return Err("the orientation holds observations the extractor did not give".into());
    }
    println!("ok: the orientation is made of even-sift's keypoints");
    Ok(())
}
