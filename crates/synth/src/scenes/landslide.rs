//! `landslide`: a soil slip on a forested hillside, flown every two months. A block of the slope
//! slides about 3 m downhill (then 1 m more), carrying its texture with it: the scarp at its head
//! lowers, the toe bulges; boulders come to rest below the toe; the forest edge above changes
//! with the season.

use std::sync::Arc;

use nalgebra::Vector3;
use timesift_core::SeededRng;

use super::*;
use crate::SynthError;
use crate::noise::Noise;
use crate::scene::{ChangeRegion, Feature, SceneSpec, Shape};
use crate::shapes::Bump;

const EPOCHS: usize = 3;
/// Downhill displacement of the block at each epoch, metres.
const DISPLACEMENT: [f64; EPOCHS] = [0.0, 3.0, 4.0];
/// The sliding block (its texture moves with it): centre and semi-axes.
const BLOCK: Bump = Bump {
    centre: (150.0, 118.0),
    a: 40.0,
    b: 50.0,
    yaw: 0.0,
    height: 1.0,
    power: 2.0,
};
const FOREST_Y: f64 = 200.0;

pub(super) fn build(scale: Scale, seed: u64) -> Result<SceneSpec, SynthError> {
    let size = image_size(scale, (512, 384), (3000, 2000));
    let flight = match scale {
        Scale::Small => nadir((60.0, 40.0), (240.0, 200.0), 150.0, 45.0, (0.6, 0.55), 1.0),
        Scale::Full => nadir((20.0, 20.0), (280.0, 220.0), 150.0, 45.0, (0.8, 0.7), 1.0),
    };
    build_block(seed, size, &flight)
}

/// The dense bench's realistic image size: the first epoch of `landslide` flown with a 12 MP
/// camera (4000 × 3000, the textures as fine as its pixels) over the middle of the slope, 3 × 3
/// images at 80 % forward and 70 % side overlap. Whatever the scale.
pub(super) fn build_12mp(seed: u64) -> Result<SceneSpec, SynthError> {
    let flight = nadir((130.0, 100.0), (170.0, 135.0), 150.0, 45.0, (0.8, 0.7), 1.0);
    let mut spec = build_block(seed, (4000, 3000), &flight)?;
    spec.epochs.truncate(1);
    spec.name = "landslide-12mp".to_string();
    Ok(spec)
}

fn build_block(
    seed: u64,
    (w, h): (u32, u32),
    flight: &NadirBlock,
) -> Result<SceneSpec, SynthError> {
    let mut rng = SeededRng::new(seed);
    let base = hillside(seed);
    let mut features = Vec::new();
    let (scarp, toe) = slide(&mut features);
    let boulders = boulders(&mut features, &mut rng);
    let regions = change_regions(scarp, toe, boulders);
    let f = 0.72 * w as f64;
    let fin = finest(f, 80.0);
    let materials = land_covers(seed, fin);
    let cover_fn = cover_by_epoch(seed, &features);
    let warp = move |e: usize, p: &Vector3<f64>| -> Vector3<f64> {
        let w = BLOCK.value(p.x, p.y).min(0.6) / 0.6;
        Vector3::new(p.x, p.y + DISPLACEMENT[e] * w, p.z)
    };
    let epochs = bimonthly_epochs(flight, (w, h), &mut rng);
    let mut spec = new_scene(
        "landslide",
        "EPSG:32632",
        Vector3::new(358_200.0, 5_080_400.0, 880.0),
        Frame::Ground,
        (0.0, 0.0, 0.3, 1001, 801),
        Arc::new(base),
        materials,
        Arc::new(cover_fn),
        epochs,
        seed,
    );
    spec.apron = 150.0;
    spec.features = features;
    spec.warp = Some(Arc::new(warp));
    spec.regions = regions;
    spec.unstable = vec![
        BLOCK.footprint(2.0),
        rect((98.0, 34.0), (202.0, 62.0)),
        rect((-1.0, 180.0), (301.0, 241.0)),
    ];
    place_control(
        &mut spec,
        &mut rng,
        (6, 4),
        (40.0, 25.0),
        (260.0, 175.0),
        3.0,
        50.0,
        &[],
    );
    Ok(spec)
}

/// The stable surface: a slope rising 0.35 m per metre north, with rolling and rough relief.
fn hillside(seed: u64) -> impl Fn(f64, f64) -> f64 + Send + Sync + 'static {
    let noise = Noise::new(seed ^ 61);
    move |x: f64, y: f64| {
        0.35 * y
            + 2.5 * noise.fbm(x, y, 0.0, 40.0, 4, 0.5)
            + 0.4 * noise.fbm(x, y, 9.0, 6.0, 3, 0.5)
    }
}

/// Adds the slide's height changes after the first epoch to `features` and returns the indices
/// of those of the scarp and of the toe.
fn slide(features: &mut Vec<Feature>) -> (Vec<usize>, Vec<usize>) {
    let (mut scarp, mut toe) = (Vec::new(), Vec::new());
    for e in 1..EPOCHS {
        let d = DISPLACEMENT[e];
        // Head lowers and toe bulges by the same volume, grown 10 % by loosening.
        let head = Bump {
            centre: (150.0, 150.0),
            a: 25.0,
            b: 12.0,
            yaw: 0.0,
            height: -0.5 * d,
            power: 2.0,
        };
        let bulge = Bump {
            centre: (150.0, 88.0),
            a: 25.0,
            b: 14.0,
            yaw: 0.0,
            height: 0.5 * d * 12.0 / 14.0 * 1.1,
            power: 2.0,
        };
        scarp.push(features.len());
        features.push(Feature {
            shape: Shape::Bump(head),
            epochs: vec![e],
        });
        toe.push(features.len());
        features.push(Feature {
            shape: Shape::Bump(bulge),
            epochs: vec![e],
        });
    }
    (scarp, toe)
}

/// Adds eight boulders coming to rest below the toe (five by the second epoch, three more by
/// the third) to `features` and returns their indices.
fn boulders(features: &mut Vec<Feature>, rng: &mut SeededRng) -> Vec<usize> {
    let mut boulders = Vec::new();
    for k in 0..8 {
        let first = if k < 5 { 1 } else { 2 };
        let b = Bump::round(
            (
                115.0 + 10.0 * k as f64 + 2.0 * rng.normal(),
                rng.uniform_range(42.0, 54.0),
            ),
            rng.uniform_range(2.0, 3.0),
            rng.uniform_range(1.0, 1.8),
            2.0,
        );
        boulders.push(features.len());
        features.push(Feature {
            shape: Shape::Bump(b),
            epochs: (first..EPOCHS).collect(),
        });
    }
    boulders
}

/// The changed regions: the scarp, the toe and the boulders, of those features.
fn change_regions(scarp: Vec<usize>, toe: Vec<usize>, boulders: Vec<usize>) -> Vec<ChangeRegion> {
    vec![
        ChangeRegion {
            name: "scarp".into(),
            description: "head of the slide lowering".into(),
            polygon: rect((120.0, 134.0), (180.0, 166.0)),
            features: scarp,
            blocks: vec![],
        },
        ChangeRegion {
            name: "toe".into(),
            description: "toe of the slide bulging".into(),
            polygon: rect((120.0, 72.0), (180.0, 104.0)),
            features: toe,
            blocks: vec![],
        },
        ChangeRegion {
            name: "boulders".into(),
            description: "boulders come to rest".into(),
            polygon: rect((100.0, 36.0), (200.0, 60.0)),
            features: boulders,
            blocks: vec![],
        },
    ]
}

/// The materials: meadow, torn ground, boulders, then the forest canopy of each epoch.
fn land_covers(seed: u64, fin: f64) -> Vec<Material> {
    vec![
        cover(seed ^ 1, [0.25, 0.34, 0.12], [0.46, 0.52, 0.26], 15.0, fin),
        cover(seed ^ 2, [0.36, 0.28, 0.20], [0.58, 0.48, 0.36], 6.0, fin),
        cover(seed ^ 3, [0.45, 0.44, 0.42], [0.68, 0.67, 0.64], 1.5, fin),
        cover(seed ^ 4, [0.04, 0.14, 0.04], [0.14, 0.30, 0.10], 4.0, fin),
        cover(seed ^ 5, [0.06, 0.12, 0.04], [0.20, 0.26, 0.08], 4.0, fin),
        cover(seed ^ 6, [0.22, 0.10, 0.03], [0.52, 0.30, 0.08], 4.0, fin),
    ]
}

/// The land cover of an epoch at a grid position: the forest above its moving edge, the
/// boulders of `features` once they have come, torn ground around the sliding block, meadow.
fn cover_by_epoch(
    seed: u64,
    features: &[Feature],
) -> impl Fn(usize, f64, f64) -> usize + Send + Sync + 'static {
    let edge = Noise::new(seed ^ 62);
    let boulder_shapes: Vec<(Bump, usize)> = features
        .iter()
        .filter_map(|f| match f.shape {
            Shape::Bump(b) if b.a < 4.0 => Some((b, f.epochs[0])),
            _ => None,
        })
        .collect();
    move |e: usize, x: f64, y: f64| -> usize {
        let edge_y = FOREST_Y + 6.0 * edge.fbm2(x, 0.0, 30.0, 3, 0.5) - 4.0 * e as f64;
        if y > edge_y {
            return 3 + e; // forest canopy: summer green, late summer, autumn
        }
        if boulder_shapes
            .iter()
            .any(|(b, first)| e >= *first && b.value(x, y) > 0.05)
        {
            return 2;
        }
        if e > 0 && BLOCK.covers(x, y, 0.0) && BLOCK.value(x, y) < 0.35 {
            return 1; // torn ground around the sliding block
        }
        0
    }
}

/// The epochs: the same drone camera (of `w` × `h` pixels) and block flown every two months.
fn bimonthly_epochs(
    flight: &NadirBlock,
    (w, h): (u32, u32),
    rng: &mut SeededRng,
) -> Vec<EpochSpec> {
    let camera_seed = rng.next_u64();
    let names = ["2023-06-15", "2023-08-16", "2023-10-17"];
    (0..EPOCHS)
        .map(|e| {
            let camera = drone_camera(w, h, camera_seed);
            let poses = flight.poses(&camera, rng);
            let light = sun(
                (160.0 + 10.0 * e as f64).to_radians(),
                (60.0 - 12.0 * e as f64).to_radians(),
            );
            drone_epoch(names[e], camera, poses, light, rng)
        })
        .collect()
}
