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

pub(super) fn build(scale: Scale, seed: u64) -> Result<SceneSpec, SynthError> {
    let mut rng = SeededRng::new(seed);
    let snap = |x: f64| snap_to_cell_boundary(x, CELL);
    let noise = Noise::new(seed ^ 11);
    let buildings = [
        ((20.0, 95.0), (62.0, 125.0), 14.0),
        ((75.0, 100.0), (105.0, 135.0), 9.0),
        ((25.0, 20.0), (60.0, 48.0), 18.0),
    ];
    let mut pads: Vec<((f64, f64), (f64, f64))> = buildings
        .iter()
        .map(|b| ((b.0.0 - 2.0, b.0.1 - 2.0), (b.1.0 + 2.0, b.1.1 + 2.0)))
        .collect();
    pads.push((
        (LOT_MIN.0 - 1.0, LOT_MIN.1 - 1.0),
        (LOT_MAX.0 + 1.0, LOT_MAX.1 + 1.0),
    ));
    let natural = {
        let noise = noise.clone();
        move |x: f64, y: f64| 3.0 + 0.01 * x + 0.006 * y + 0.8 * noise.fbm(x, y, 0.0, 70.0, 4, 0.5)
    };
    let levels: Vec<f64> = pads
        .iter()
        .map(|(a, b)| natural(0.5 * (a.0 + b.0), 0.5 * (a.1 + b.1)))
        .collect();
    let pads_for_base = pads.clone();
    let levels_for_base = levels.clone();
    let base = move |x: f64, y: f64| {
        let mut z = natural(x, y);
        for (p, level) in pads_for_base.iter().zip(&levels_for_base) {
            let w = pad_weight(p.0, p.1, 4.0, x, y);
            z += w * (level - z);
        }
        z
    };
    let n_epochs = 8;
    let mut blocks = Vec::new();
    for (k, b) in buildings.iter().enumerate() {
        let level = levels[k];
        blocks.push(PlacedBlock {
            block: Block {
                min: (snap(b.0.0), snap(b.0.1)),
                max: (snap(b.1.0), snap(b.1.1)),
                base: level,
                top: level + b.2,
            },
            epochs: (0..n_epochs).collect(),
            material: 4,
        });
    }
    // Car park: rows of stalls 2.5 m wide; each car stays for a run of flights.
    let lot_level = levels[3];
    let mut regions = Vec::new();
    for (row, y) in [24.0, 38.0, 52.0, 66.0].iter().enumerate() {
        let mut members = Vec::new();
        for stall in 0..24 {
            let x = LOT_MIN.0 + 2.0 + 2.5 * stall as f64;
            if rng.uniform() < 0.2 {
                continue;
            }
            let arrive = rng.below(n_epochs);
            let stay = 1 + rng.below(n_epochs);
            let epochs: Vec<usize> = (arrive..(arrive + stay).min(n_epochs)).collect();
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
    let (w, h) = image_size(scale, (512, 384), (3000, 2000));
    let fin = finest(
        0.72 * w as f64,
        match scale {
            Scale::Small => 110.0,
            Scale::Full => 75.0,
        },
    );
    let materials = vec![
        cover(seed ^ 1, [0.16, 0.30, 0.10], [0.34, 0.52, 0.20], 20.0, fin),
        cover(seed ^ 2, [0.22, 0.22, 0.23], [0.36, 0.36, 0.37], 8.0, fin),
        cover(seed ^ 3, [0.80, 0.80, 0.78], [0.92, 0.92, 0.90], 2.0, fin),
        cover(seed ^ 4, [0.45, 0.42, 0.38], [0.62, 0.58, 0.52], 10.0, fin),
        cover(seed ^ 5, [0.35, 0.33, 0.32], [0.58, 0.55, 0.52], 6.0, fin),
        cover(seed ^ 6, [0.55, 0.05, 0.05], [0.75, 0.12, 0.10], 1.0, fin),
        cover(seed ^ 7, [0.75, 0.75, 0.78], [0.90, 0.90, 0.92], 1.0, fin),
        cover(seed ^ 8, [0.05, 0.08, 0.25], [0.12, 0.15, 0.40], 1.0, fin),
        cover(seed ^ 9, [0.04, 0.04, 0.04], [0.12, 0.12, 0.12], 1.0, fin),
    ];
    let paths = [(10.0, 70.0, 200.0, 80.0), (95.0, 0.0, 103.0, 150.0)];
    let cover_fn = move |_e: usize, x: f64, y: f64| -> usize {
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
    };
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
    let epochs = (0..n_epochs)
        .map(|k| {
            let camera = drone_camera(w, h, camera_seed);
            let poses = flight.poses(&camera, &mut rng);
            let hour = 9.0 + k as f64;
            let light = sun(
                (95.0 + 22.0 * k as f64).to_radians(),
                (35.0 + 25.0 * (1.0 - ((hour - 13.0) / 5.0).powi(2))).to_radians(),
            );
            let name = format!("2025-06-12_{:02}00", hour as u32);
            let mut epoch = drone_epoch(&name, camera, poses, light, &mut rng);
            epoch.shadows = true;
            epoch
        })
        .collect();
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
