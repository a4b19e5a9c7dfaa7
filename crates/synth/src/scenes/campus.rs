//! `campus`: a stable site flown eight times in one day. Buildings, lawns, paths and a car park;
//! nothing changes but the parked cars (and the sun, which moves the shadows). Every difference
//! elsewhere is the noise floor of the method.

use std::sync::Arc;

use nalgebra::Vector3;
use timesift_core::SeededRng;

use super::*;
use crate::SynthError;
use crate::noise::Noise;
use crate::scene::{ChangeRegion, PlacedBlock, SceneSpec};
use crate::shapes::Block;

const CELL: f64 = 0.25;
const LOT_MIN: (f64, f64) = (120.0, 20.0);
const LOT_MAX: (f64, f64) = (185.0, 75.0);

/// Flights, one an hour from 09:00.
const EPOCHS: usize = 8;
/// A building: south-west corner, north-east corner, height.
type Building = ((f64, f64), (f64, f64), f64);
/// The buildings.
const BUILDINGS: [Building; 3] = [
    ((20.0, 95.0), (62.0, 125.0), 14.0),
    ((75.0, 100.0), (105.0, 135.0), 9.0),
    ((25.0, 20.0), (60.0, 48.0), 18.0),
];

/// South-west and north-east corners.
type Rectangle = ((f64, f64), (f64, f64));

pub(super) fn build(scale: Scale, seed: u64) -> Result<SceneSpec, SynthError> {
    let mut rng = SeededRng::new(seed);
    let pads = levelled_pads();
    let natural = natural_surface(seed);
    let levels: Vec<f64> = pads
        .iter()
        .map(|(a, b)| natural(0.5 * (a.0 + b.0), 0.5 * (a.1 + b.1)))
        .collect();
    let base = base_with_levelled_pads(natural, pads, levels.clone());
    let mut blocks = buildings(&levels);
    let regions = parked_cars(&mut blocks, levels[3], &mut rng);
    let (w, h) = image_size(scale, (512, 384), (3000, 2000));
    let fin = finest(
        0.72 * w as f64,
        match scale {
            Scale::Small => 110.0,
            Scale::Full => 75.0,
        },
    );
    let materials = land_covers(seed, fin);
    let cover_fn = cover_of_ground();
    let epochs = hourly_epochs(scale, (w, h), &mut rng);
    let mut spec = new_scene(
        "campus",
        "EPSG:32633",
        Vector3::new(592_300.0, 5_763_800.0, 34.0),
        Frame::Ground,
        (0.0, 0.0, CELL, 801, 601),
        Arc::new(base),
        materials,
        Arc::new(cover_fn),
        epochs,
        seed,
    );
    spec.apron = 150.0;
    spec.blocks = blocks;
    spec.regions = regions;
    spec.unstable = vec![rect(
        (LOT_MIN.0 - 1.0, LOT_MIN.1 - 1.0),
        (LOT_MAX.0 + 1.0, LOT_MAX.1 + 1.0),
    )];
    place_control(
        &mut spec,
        &mut rng,
        (6, 4),
        (15.0, 15.0),
        (185.0, 135.0),
        4.0,
        35.0,
        &[],
    );
    Ok(spec)
}

/// The levelled pads: one 2 m around each building, then one 1 m around the car park.
fn levelled_pads() -> Vec<Rectangle> {
    let mut pads: Vec<Rectangle> = BUILDINGS
        .iter()
        .map(|b| ((b.0.0 - 2.0, b.0.1 - 2.0), (b.1.0 + 2.0, b.1.1 + 2.0)))
        .collect();
    pads.push((
        (LOT_MIN.0 - 1.0, LOT_MIN.1 - 1.0),
        (LOT_MAX.0 + 1.0, LOT_MAX.1 + 1.0),
    ));
    pads
}

/// The ground before levelling: a gentle slope with low undulations.
fn natural_surface(seed: u64) -> impl Fn(f64, f64) -> f64 + Send + Sync + 'static {
    let noise = Noise::new(seed ^ 11);
    move |x: f64, y: f64| 3.0 + 0.01 * x + 0.006 * y + 0.8 * noise.fbm(x, y, 0.0, 70.0, 4, 0.5)
}

/// The stable surface: the natural ground with each pad levelled at its height in `levels`,
/// blended into the ground over 4 m.
fn base_with_levelled_pads(
    natural: impl Fn(f64, f64) -> f64 + Send + Sync + 'static,
    pads: Vec<Rectangle>,
    levels: Vec<f64>,
) -> impl Fn(f64, f64) -> f64 + Send + Sync + 'static {
    move |x: f64, y: f64| {
        let mut z = natural(x, y);
        for (p, level) in pads.iter().zip(&levels) {
            let w = pad_weight(p.0, p.1, 4.0, x, y);
            z += w * (level - z);
        }
        z
    }
}

/// The buildings, on their pads' levels (the first entries of `levels`), in every epoch.
fn buildings(levels: &[f64]) -> Vec<PlacedBlock> {
    let snap = |x: f64| snap_to_cell_boundary(x, CELL);
    let mut blocks = Vec::new();
    for (k, b) in BUILDINGS.iter().enumerate() {
        let level = levels[k];
        blocks.push(PlacedBlock {
            block: Block {
                min: (snap(b.0.0), snap(b.0.1)),
                max: (snap(b.1.0), snap(b.1.1)),
                base: level,
                top: level + b.2,
            },
            epochs: (0..EPOCHS).collect(),
            material: 4,
        });
    }
    blocks
}

/// Adds the parked cars to `blocks` and returns a changed region per row of the car park:
/// stalls 2.5 m wide at `lot_level`; each car stays for a run of flights.
fn parked_cars(
    blocks: &mut Vec<PlacedBlock>,
    lot_level: f64,
    rng: &mut SeededRng,
) -> Vec<ChangeRegion> {
    let snap = |x: f64| snap_to_cell_boundary(x, CELL);
    let mut regions = Vec::new();
    for (row, y) in [24.0, 38.0, 52.0, 66.0].iter().enumerate() {
        let mut members = Vec::new();
        for stall in 0..24 {
            let x = LOT_MIN.0 + 2.0 + 2.5 * stall as f64;
            if rng.uniform() < 0.2 {
                continue;
            }
            let arrive = rng.below(EPOCHS);
            let stay = 1 + rng.below(EPOCHS);
            let epochs: Vec<usize> = (arrive..(arrive + stay).min(EPOCHS)).collect();
            members.push(blocks.len());
            blocks.push(PlacedBlock {
                block: Block {
                    min: (snap(x + 0.35), snap(y - 2.25)),
                    max: (snap(x + 2.15), snap(y + 2.25)),
                    base: lot_level,
                    top: lot_level + rng.uniform_range(1.4, 1.8),
                },
                epochs,
                material: 5 + rng.below(4),
            });
        }
        regions.push(ChangeRegion {
            name: format!("parking-row-{}", row + 1),
            description: "cars parked and leaving".into(),
            polygon: rect((LOT_MIN.0, y - 5.0), (LOT_MAX.0, y + 5.0)),
            features: vec![],
            blocks: members,
        });
    }
    regions
}

/// The materials: lawn, asphalt, stall lines, paths, roofs, then the cars' four paints.
fn land_covers(seed: u64, fin: f64) -> Vec<Material> {
    vec![
        cover(seed ^ 1, [0.16, 0.30, 0.10], [0.34, 0.52, 0.20], 20.0, fin),
        cover(seed ^ 2, [0.22, 0.22, 0.23], [0.36, 0.36, 0.37], 8.0, fin),
        cover(seed ^ 3, [0.80, 0.80, 0.78], [0.92, 0.92, 0.90], 2.0, fin),
        cover(seed ^ 4, [0.45, 0.42, 0.38], [0.62, 0.58, 0.52], 10.0, fin),
        cover(seed ^ 5, [0.35, 0.33, 0.32], [0.58, 0.55, 0.52], 6.0, fin),
        cover(seed ^ 6, [0.55, 0.05, 0.05], [0.75, 0.12, 0.10], 1.0, fin),
        cover(seed ^ 7, [0.75, 0.75, 0.78], [0.90, 0.90, 0.92], 1.0, fin),
        cover(seed ^ 8, [0.05, 0.08, 0.25], [0.12, 0.15, 0.40], 1.0, fin),
        cover(seed ^ 9, [0.04, 0.04, 0.04], [0.12, 0.12, 0.12], 1.0, fin),
    ]
}

/// The land cover at a grid position, the same in every epoch: the car park with its stall
/// lines, the paths, lawn elsewhere.
fn cover_of_ground() -> impl Fn(usize, f64, f64) -> usize + Send + Sync + 'static {
    let paths = [(10.0, 70.0, 200.0, 80.0), (95.0, 0.0, 103.0, 150.0)];
    move |_e: usize, x: f64, y: f64| -> usize {
        let in_lot = x > LOT_MIN.0 && x < LOT_MAX.0 && y > LOT_MIN.1 && y < LOT_MAX.1;
        if in_lot {
            // White stall lines between cars: 0.15 m wide every 2.5 m, along each row.
            let s = (x - LOT_MIN.0 - 2.0).rem_euclid(2.5);
            let row_line = [24.0, 38.0, 52.0, 66.0].iter().any(|r| (y - r).abs() < 2.5);
            return if row_line && s < 0.15 { 2 } else { 1 };
        }
        if paths
            .iter()
            .any(|p| x > p.0 && x < p.2 && y > p.1 && y < p.3)
        {
            return 3;
        }
        0
    }
}

/// The epochs: the same drone camera (of `w` × `h` pixels) and block flown once an hour from
/// 09:00, with the sun moving and casting shadows.
fn hourly_epochs(scale: Scale, (w, h): (u32, u32), rng: &mut SeededRng) -> Vec<EpochSpec> {
    let camera_seed = rng.next_u64();
    let flight = match scale {
        Scale::Small => nadir(
            (40.0, 45.0),
            (160.0, 100.0),
            115.0 * 640.0 / w as f64,
            4.0,
            (0.6, 0.5),
            1.0,
        ),
        Scale::Full => nadir((10.0, 10.0), (190.0, 140.0), 80.0, 4.0, (0.7, 0.6), 1.0),
    };
    (0..EPOCHS)
        .map(|k| {
            let camera = drone_camera(w, h, camera_seed);
            let poses = flight.poses(&camera, rng);
            let hour = 9.0 + k as f64;
            let light = sun(
                (95.0 + 22.0 * k as f64).to_radians(),
                (35.0 + 25.0 * (1.0 - ((hour - 13.0) / 5.0).powi(2))).to_radians(),
            );
            let name = format!("2025-06-12_{:02}00", hour as u32);
            let mut epoch = drone_epoch(&name, camera, poses, light, rng);
            epoch.shadows = true;
            epoch
        })
        .collect()
}
