//! `orchard`: rows of fruit trees flown every three weeks in spring, nadir and oblique (after
//! the Mornag olive orchards). Tree crowns grow; the grass between the rows changes colour. The
//! dirt tracks and bare field margins around the orchard are stable.

use std::sync::Arc;

use nalgebra::Vector3;
use timesift_core::SeededRng;

use super::*;
use crate::SynthError;
use crate::flight::ring;
use crate::noise::Noise;
use crate::scene::{ChangeRegion, Feature, SceneSpec, Shape};
use crate::shapes::Bump;

const ROWS: usize = 7;
const TREES: usize = 16;
const ROW_Y0: f64 = 21.0;
const ROW_DY: f64 = 8.0;
const TREE_X0: f64 = 15.0;
const TREE_DX: f64 = 6.0;
const EPOCHS: usize = 4;

/// The grass between the rows, whose colour changes (west, south, east, north edges).
const GRASS: (f64, f64, f64, f64) = (8.0, 14.0, 112.0, 74.0);

/// Tree crowns, `[row][tree][epoch]`.
type Crowns = Vec<Vec<[Bump; EPOCHS]>>;

pub(super) fn build(scale: Scale, seed: u64) -> Result<SceneSpec, SynthError> {
    let mut rng = SeededRng::new(seed);
    let noise = Noise::new(seed ^ 31);
    let base = move |x: f64, y: f64| 0.004 * x + 0.3 * noise.fbm(x, y, 0.0, 50.0, 4, 0.5);
    let (crowns, features, regions) = tree_rows(&mut rng);
    let (w, h) = image_size(scale, (512, 384), (3000, 2000));
    let f = 0.72 * w as f64;
    let fin = finest(f, 40.0);
    let materials = land_covers(seed, fin);
    let cover_fn = cover_by_epoch(crowns);
    let epochs = three_weekly_epochs(scale, (w, h), &mut rng);
    let (ox0, oy0, ox1, oy1) = GRASS;
    let mut spec = new_scene(
        "orchard",
        "EPSG:32632",
        Vector3::new(611_200.0, 4_059_300.0, 12.0),
        Frame::Ground,
        (0.0, 0.0, 0.15, 801, 601),
        Arc::new(base),
        materials,
        Arc::new(cover_fn),
        epochs,
        seed,
    );
    spec.apron = 80.0;
    spec.features = features;
    spec.target_radius = 0.25;
    spec.regions = regions;
    spec.unstable = vec![rect((ox0, oy0), (ox1, oy1))];
    place_control(
        &mut spec,
        &mut rng,
        (6, 4),
        (2.0, 2.0),
        (118.0, 88.0),
        1.5,
        25.0,
        &[],
    );
    Ok(spec)
}

/// The rows of trees, each crown growing every epoch: the crowns, their height changes, and a
/// changed region per row.
fn tree_rows(rng: &mut SeededRng) -> (Crowns, Vec<Feature>, Vec<ChangeRegion>) {
    let mut crowns = vec![vec![[Bump::round((0.0, 0.0), 1.0, 1.0, 2.0); EPOCHS]; TREES]; ROWS];
    let mut features = Vec::new();
    let mut regions = Vec::new();
    for (r, row) in crowns.iter_mut().enumerate() {
        let mut members = Vec::new();
        for (t, tree) in row.iter_mut().enumerate() {
            let centre = (
                TREE_X0 + TREE_DX * t as f64 + 0.3 * rng.normal(),
                ROW_Y0 + ROW_DY * r as f64 + 0.3 * rng.normal(),
            );
            let (r0, h0) = (rng.uniform_range(1.2, 1.6), rng.uniform_range(2.4, 3.0));
            let growth = rng.uniform_range(0.08, 0.16);
            for (e, crown) in tree.iter_mut().enumerate() {
                *crown = Bump::round(
                    centre,
                    r0 + growth * e as f64,
                    h0 + 1.3 * growth * e as f64,
                    2.0,
                );
                members.push(features.len());
                features.push(Feature {
                    shape: Shape::Bump(*crown),
                    epochs: vec![e],
                });
            }
        }
        let y = ROW_Y0 + ROW_DY * r as f64;
        regions.push(ChangeRegion {
            name: format!("row-{}", r + 1),
            description: "tree crowns growing".into(),
            polygon: rect(
                (TREE_X0 - 4.0, y - 3.9),
                (TREE_X0 + TREE_DX * TREES as f64, y + 3.9),
            ),
            features: members,
            blocks: vec![],
        });
    }
    (crowns, features, regions)
}

/// The materials: bare soil, crowns, dirt track, then the grass of each epoch, fresh green
/// drying to straw.
fn land_covers(seed: u64, fin: f64) -> Vec<Material> {
    let mut materials = vec![
        cover(seed ^ 1, [0.45, 0.36, 0.26], [0.66, 0.55, 0.42], 25.0, fin),
        cover(seed ^ 2, [0.05, 0.14, 0.04], [0.20, 0.36, 0.12], 1.2, fin),
        cover(seed ^ 3, [0.55, 0.52, 0.47], [0.72, 0.68, 0.62], 8.0, fin),
    ];
    // Grass between the rows, one colour per epoch: fresh green drying to straw.
    let grass = [
        ([0.18, 0.34, 0.10], [0.36, 0.55, 0.22]),
        ([0.24, 0.38, 0.12], [0.44, 0.58, 0.24]),
        ([0.36, 0.40, 0.16], [0.58, 0.60, 0.30]),
        ([0.48, 0.44, 0.24], [0.72, 0.66, 0.40]),
    ];
    for (e, (d, l)) in grass.iter().enumerate() {
        materials.push(cover(seed ^ (10 + e as u64), *d, *l, 6.0, fin));
    }
    materials
}

/// The land cover of an epoch at a grid position: the tree's crown of that epoch, the grass
/// between the rows, the dirt tracks, bare soil elsewhere.
fn cover_by_epoch(crowns: Crowns) -> impl Fn(usize, f64, f64) -> usize + Send + Sync + 'static {
    let (ox0, oy0, ox1, oy1) = GRASS;
    move |e: usize, x: f64, y: f64| -> usize {
        let r = ((y - ROW_Y0) / ROW_DY).round();
        let t = ((x - TREE_X0) / TREE_DX).round();
        if r >= 0.0 && t >= 0.0 && (r as usize) < ROWS && (t as usize) < TREES {
            let crown = crowns[r as usize][t as usize][e];
            if crown.value(x, y) > 0.02 {
                return 1;
            }
        }
        if x > ox0 && x < ox1 && y > oy0 && y < oy1 {
            return 3 + e;
        }
        if (y - 8.0).abs() < 2.0 || (x - 4.0).abs() < 2.0 {
            return 2; // dirt track
        }
        0
    }
}

/// The epochs: the same drone camera (of `w` × `h` pixels) flying a nadir block and a ring of
/// obliques every three weeks.
fn three_weekly_epochs(scale: Scale, (w, h): (u32, u32), rng: &mut SeededRng) -> Vec<EpochSpec> {
    let camera_seed = rng.next_u64();
    let (flight, obliques) = match scale {
        Scale::Small => (
            nadir((25.0, 22.0), (95.0, 66.0), 50.0, 0.3, (0.6, 0.5), 0.5),
            3,
        ),
        Scale::Full => (
            nadir((10.0, 10.0), (110.0, 80.0), 35.0, 0.3, (0.75, 0.65), 0.5),
            12,
        ),
    };
    let names = ["2024-03-04", "2024-03-25", "2024-04-15", "2024-05-06"];
    (0..EPOCHS)
        .map(|e| {
            let camera = drone_camera(w, h, camera_seed);
            let mut poses = flight.poses(&camera, rng);
            let centre = Vector3::new(60.0, 45.0, 0.0);
            poses.extend(ring((60.0, 45.0), 38.0, 30.0, &centre, obliques, rng));
            let light = sun(
                (140.0 + 10.0 * e as f64).to_radians(),
                (48.0 + 4.0 * e as f64).to_radians(),
            );
            drone_epoch(names[e], camera, poses, light, rng)
        })
        .collect()
}
