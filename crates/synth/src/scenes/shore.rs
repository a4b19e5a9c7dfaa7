//! `shore`: an intertidal rocky shore platform flown monthly at low tide. Sand fills the gullies
//! between the rocks (more each month), and the water left in pools and at the sea's edge differs
//! from flight to flight. The rock outcrops landward are stable.

use std::sync::Arc;

use nalgebra::Vector3;
use timesift_core::SeededRng;

use super::*;
use crate::SynthError;
use crate::noise::Noise;
use crate::scene::{ChangeRegion, Feature, SceneSpec, Shape};
use crate::shapes::Bump;
use crate::terrain::Heightfield;

const EPOCHS: usize = 4;

pub(super) fn build(scale: Scale, seed: u64) -> Result<SceneSpec, SynthError> {
    let mut rng = SeededRng::new(seed);
    let rock = rock_relief(seed);
    let rock_for_base = rock.clone();
    let base = move |x: f64, y: f64| 0.012 * x + rock_for_base(x, y);
    // Sand patches in the gullies, each thicker every month; pools placed apart from them.
    let mut unstable = vec![rect((-1.0, -1.0), (16.0, 101.0))];
    let SandPatches {
        features,
        regions,
        placed,
    } = sand_patches(&mut unstable, &mut rng);
    let pools = pools(&placed, &mut unstable, &mut rng);
    let (w, h) = image_size(scale, (512, 384), (3000, 2000));
    let f = 0.72 * w as f64;
    let fin = finest(f, 40.0);
    let materials = land_covers(seed, fin);
    let cover_fn = cover_by_epoch(pools, placed, &rock);
    let epochs = monthly_epochs(scale, (w, h), &mut rng);
    let mut spec = new_scene(
        "shore",
        "EPSG:32755",
        Vector3::new(520_400.0, 5_251_800.0, 0.0),
        Frame::Ground,
        (0.0, 0.0, 0.15, 1001, 667),
        Arc::new(base),
        materials,
        Arc::new(cover_fn),
        epochs,
        seed,
    );
    spec.apron = 60.0;
    spec.features = features;
    spec.target_radius = 0.25;
    spec.regions = regions;
    spec.unstable = unstable;
    place_control(
        &mut spec,
        &mut rng,
        (6, 4),
        (20.0, 8.0),
        (145.0, 92.0),
        1.5,
        25.0,
        &[],
    );
    Ok(spec)
}

/// The rock platform's relief: ridges with gullies between them, and rough rock.
fn rock_relief(seed: u64) -> impl Fn(f64, f64) -> f64 + Clone + Send + Sync + 'static {
    let noise = Noise::new(seed ^ 51);
    move |x: f64, y: f64| {
        let ridges = noise.fbm(x, y, 0.0, 9.0, 4, 0.5);
        0.9 * (ridges + 0.05).max(0.0) + 0.15 * noise.fbm(x, y, 5.0, 1.5, 3, 0.5)
    }
}

/// The sand filling the gullies: its height changes, a changed region per patch, and the
/// patches' footprints (at height 1).
struct SandPatches {
    features: Vec<Feature>,
    regions: Vec<ChangeRegion>,
    placed: Vec<Bump>,
}

/// Up to six sand patches drawn apart from one another, each thicker every month; their
/// surroundings are added to `unstable`.
fn sand_patches(unstable: &mut Vec<Vec<[f64; 2]>>, rng: &mut SeededRng) -> SandPatches {
    let mut features = Vec::new();
    let mut regions = Vec::new();
    let mut placed: Vec<Bump> = Vec::new();
    for k in 0..6 {
        for _ in 0..200 {
            let b = Bump {
                centre: (
                    rng.uniform_range(30.0, 135.0),
                    rng.uniform_range(12.0, 88.0),
                ),
                a: rng.uniform_range(6.0, 10.0),
                b: rng.uniform_range(3.0, 5.0),
                yaw: rng.uniform_range(0.0, std::f64::consts::PI),
                height: 1.0,
                power: 2.0,
            };
            if placed
                .iter()
                .all(|p| (p.centre.0 - b.centre.0).hypot(p.centre.1 - b.centre.1) > p.a + b.a + 4.0)
            {
                let mut members = Vec::new();
                for e in 1..EPOCHS {
                    members.push(features.len());
                    features.push(Feature {
                        shape: Shape::Bump(Bump {
                            height: 0.12 * e as f64,
                            ..b
                        }),
                        epochs: vec![e],
                    });
                }
                regions.push(ChangeRegion {
                    name: format!("sand-{}", k + 1),
                    description: "sand filling a gully".into(),
                    polygon: b.footprint(0.5),
                    features: members,
                    blocks: vec![],
                });
                unstable.push(b.footprint(1.5));
                placed.push(b);
                break;
            }
        }
    }
    SandPatches {
        features,
        regions,
        placed,
    }
}

/// Up to four rock pools drawn apart from the sand patches and from one another; their
/// surroundings are added to `unstable`.
fn pools(placed: &[Bump], unstable: &mut Vec<Vec<[f64; 2]>>, rng: &mut SeededRng) -> Vec<Bump> {
    let mut pools: Vec<Bump> = Vec::new();
    for _ in 0..300 {
        if pools.len() == 4 {
            break;
        }
        let b = Bump::round(
            (
                rng.uniform_range(25.0, 140.0),
                rng.uniform_range(10.0, 90.0),
            ),
            rng.uniform_range(2.5, 4.5),
            1.0,
            1.0,
        );
        if placed.iter().chain(&pools).all(|p| {
            (p.centre.0 - b.centre.0).hypot(p.centre.1 - b.centre.1) > p.a.max(p.b) + b.a + 4.0
        }) {
            unstable.push(b.footprint(1.0));
            pools.push(b);
        }
    }
    pools
}

/// The materials: rock, sand, water, algae.
fn land_covers(seed: u64, fin: f64) -> Vec<Material> {
    vec![
        cover(seed ^ 1, [0.22, 0.20, 0.18], [0.48, 0.45, 0.40], 4.0, fin),
        cover(seed ^ 2, [0.72, 0.64, 0.48], [0.86, 0.79, 0.62], 3.0, fin),
        cover_with_contrast(
            seed ^ 3,
            [0.05, 0.12, 0.14],
            [0.10, 0.20, 0.22],
            10.0,
            fin,
            0.5,
        ),
        cover(seed ^ 4, [0.15, 0.22, 0.08], [0.30, 0.38, 0.14], 2.0, fin),
    ]
}

/// The land cover of an epoch at a grid position: the sea up to its edge of the day, the pools
/// with their water level, the sand after the first epoch, algae in the low gullies of `rock`,
/// rock elsewhere.
fn cover_by_epoch(
    pools: Vec<Bump>,
    sand: Vec<Bump>,
    rock: impl Fn(f64, f64) -> f64,
) -> impl Fn(usize, f64, f64) -> usize + Send + Sync + 'static {
    // The rock relief tabulated on a 0.25 m lattice (bilinear between nodes): the cover function
    // runs for every ray sample, the relief's seven noise octaves would dominate rendering.
    let relief = Heightfield::from_fn((-70.0, -70.0), 0.25, 1161, 961, rock);
    move |e: usize, x: f64, y: f64| -> usize {
        let sea_edge = 8.0 + 2.5 * ((e * 7) % 3) as f64;
        if x < sea_edge {
            return 2;
        }
        for p in &pools {
            if p.covers(x, y, 0.0) {
                let level = 0.5 + 0.15 * ((e * 5) % 4) as f64;
                return if p.value(x, y) > 1.0 - level { 2 } else { 3 };
            }
        }
        if e > 0 && sand.iter().any(|b| b.value(x, y) > 0.25) {
            return 1;
        }
        if relief.bilinear(x, y).unwrap_or(1.0) < 0.02 {
            3
        } else {
            0
        } // algae in the low gullies
    }
}

/// The epochs: the same drone camera (of `w` × `h` pixels) and block flown monthly at low tide.
fn monthly_epochs(scale: Scale, (w, h): (u32, u32), rng: &mut SeededRng) -> Vec<EpochSpec> {
    let camera_seed = rng.next_u64();
    let flight = match scale {
        Scale::Small => nadir((30.0, 25.0), (120.0, 75.0), 50.0, 1.0, (0.5, 0.4), 0.5),
        Scale::Full => nadir((10.0, 10.0), (140.0, 90.0), 40.0, 1.0, (0.75, 0.65), 0.5),
    };
    let names = ["2023-01-18", "2023-02-16", "2023-03-17", "2023-04-15"];
    (0..EPOCHS)
        .map(|e| {
            let camera = drone_camera(w, h, camera_seed);
            let poses = flight.poses(&camera, rng);
            let light = sun(
                (20.0 + 15.0 * e as f64).to_radians(),
                (55.0 - 6.0 * e as f64).to_radians(),
            );
            drone_epoch(names[e], camera, poses, light, rng)
        })
        .collect()
}
