//! `corridor`: a coastal corridor flown along its axis in two nadir strips, the case where check
//! points cannot see what goes wrong. Across it, from the sea: water whose edge moves from
//! flight to flight, a sand beach accreting smoothly (decimetres a month, its texture
//! persisting), a narrow band of stable dune grass — the only ground that looks the same in
//! every epoch — and farmland whose crops change cover between flights (stable ground, new
//! texture). Control points of the reference epoch lie along the band, so they spread little
//! across the corridor; every epoch's GNSS carries a bias of its own. A roll of an epoch about
//! the corridor's axis shows in the stable-area DoD (over the band and the farmland) as a tilt
//! across it, not at the check points.
//!
//! `corridor-tracks` ([`Layout::Tracks`]) is the same corridor with stable ground that looks
//! alike across its width: two gravel farm tracks run from the dunes to the far edge between
//! the fields, and two more control points stand on them, off the dune band. There the
//! inter-epoch ties and the control spread across the corridor, so the tie points' tilt and
//! the ties' spread are judged on their merits.

use std::sync::Arc;

use nalgebra::Vector3;
use timesift_core::SeededRng;

use super::*;
use crate::SynthError;
use crate::noise::Noise;
use crate::scene::{ChangeRegion, Feature, SceneSpec, Shape};
use crate::shapes::Bump;

const EPOCHS: usize = 3;
/// The corridor's length (x) and width (y), metres.
const LENGTH: f64 = 300.0;
const WIDTH: f64 = 110.0;
/// Across the corridor (y): the beach's foot (mean water line), its top, and the top of the
/// stable band of dune grass; farmland beyond.
const BEACH_FOOT: f64 = 22.0;
const BEACH_TOP: f64 = 52.0;
const BAND_TOP: f64 = 74.0;

/// Where one field behind the dunes ends and the next begins (x); the farm tracks of
/// [`Layout::Tracks`] run along these edges.
const FIELD_EDGES: [f64; 2] = [95.0, 180.0];
/// Half the width of a track, metres.
const TRACK_HALF_WIDTH: f64 = 2.0;

/// What ground ties the corridor's epochs across its width.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Layout {
    /// Only the dune band looks alike in every epoch (`corridor`).
    Band,
    /// Gravel tracks across the farmland too, with a control point on each (`corridor-tracks`).
    Tracks,
}

pub(super) fn build(scale: Scale, seed: u64, layout: Layout) -> Result<SceneSpec, SynthError> {
    let mut rng = SeededRng::new(seed);
    let base = beach_and_dunes(seed);
    let (features, regions) = accretion();
    let mut unstable = vec![rect((-1.0, -1.0), (LENGTH + 1.0, BEACH_TOP + 2.0))];
    let (w, h) = image_size(scale, (512, 384), (3000, 2000));
    let f = 0.72 * w as f64;
    let altitude = 60.0;
    let fin = finest(f, altitude);
    let materials = land_covers(seed, fin);
    let cover_fn = cover_by_epoch(seed, layout);
    let epochs = monthly_epochs(scale, (w, h), altitude, &mut rng);
    let mut spec = new_scene(
        match layout {
            Layout::Band => "corridor",
            Layout::Tracks => "corridor-tracks",
        },
        "EPSG:32630",
        Vector3::new(612_300.0, 5_364_900.0, 0.0),
        Frame::Ground,
        (
            0.0,
            0.0,
            0.25,
            (LENGTH / 0.25) as usize + 1,
            (WIDTH / 0.25) as usize + 1,
        ),
        Arc::new(base),
        materials,
        Arc::new(cover_fn),
        epochs,
        seed,
    );
    spec.apron = 60.0;
    spec.features = features;
    spec.regions = regions;
    spec.unstable = std::mem::take(&mut unstable);
    // Control along the band, as a surveyor walking the dunes would place it.
    place_control(
        &mut spec,
        &mut rng,
        (5, 4),
        (15.0, BEACH_TOP + 4.0),
        (285.0, BAND_TOP - 4.0),
        1.5,
        45.0,
        &[],
    );
    if layout == Layout::Tracks {
        track_control(&mut spec, &mut rng);
    }
    Ok(spec)
}

/// One more control point on each track, well behind the dunes, numbered after the others.
fn track_control(spec: &mut SceneSpec, rng: &mut SeededRng) {
    let taken: Vec<(f64, f64)> = spec
        .gcps
        .iter()
        .chain(&spec.checkpoints)
        .map(|p| p.at)
        .collect();
    for x in FIELD_EDGES {
        let near = (x - 0.5, BAND_TOP + 18.0);
        let far = (x + 0.5, WIDTH - 8.0);
        let mut point = place_points(spec, rng, 1, "GCP", near, far, 1.5, 10.0, &taken);
        for p in &mut point {
            p.name = format!("GCP{}", spec.gcps.len() + 1);
        }
        spec.gcps.extend(point);
    }
}

/// The stable surface: the beach rises 2 m from the water line to the dunes, which undulate
/// gently; the farmland behind is nearly flat.
fn beach_and_dunes(seed: u64) -> impl Fn(f64, f64) -> f64 + Send + Sync + 'static {
    let noise = Noise::new(seed ^ 81);
    move |x: f64, y: f64| {
        let beach = 2.0 * ((y - BEACH_FOOT) / (BEACH_TOP - BEACH_FOOT)).clamp(0.0, 1.0);
        let dune = if y > BEACH_TOP {
            1.2 * noise.fbm(x, y, 0.0, 25.0, 4, 0.5).max(-0.5)
        } else {
            0.0
        };
        beach + dune + 0.15 * noise.fbm(x, y, 3.0, 4.0, 3, 0.5) - 0.002 * y
    }
}

/// Sand accreting smoothly on two stretches of the beach, more every month: the height
/// changes and a changed region per stretch.
fn accretion() -> (Vec<Feature>, Vec<ChangeRegion>) {
    let mut features = Vec::new();
    let mut regions = Vec::new();
    for (k, centre_x) in [80.0, 210.0].into_iter().enumerate() {
        let bump = Bump {
            centre: (centre_x, 0.5 * (BEACH_FOOT + BEACH_TOP)),
            a: 45.0,
            b: 12.0,
            yaw: 0.0,
            height: 1.0,
            power: 2.0,
        };
        let mut members = Vec::new();
        for e in 1..EPOCHS {
            members.push(features.len());
            features.push(Feature {
                shape: Shape::Bump(Bump {
                    height: 0.25 * e as f64,
                    ..bump
                }),
                epochs: vec![e],
            });
        }
        regions.push(ChangeRegion {
            name: format!("accretion-{}", k + 1),
            description: "sand accreting on the beach".into(),
            polygon: bump.footprint(0.5),
            features: members,
            blocks: vec![],
        });
    }
    (features, regions)
}

/// The materials, indexed as [`cover_by_epoch`] returns them.
fn land_covers(seed: u64, fin: f64) -> Vec<Material> {
    vec![
        // 0: dune grass (the stable band)
        cover(seed ^ 1, [0.30, 0.34, 0.16], [0.58, 0.60, 0.36], 5.0, fin),
        // 1: sand
        cover(seed ^ 2, [0.66, 0.58, 0.42], [0.86, 0.78, 0.60], 3.0, fin),
        // 2: water
        cover_with_contrast(
            seed ^ 3,
            [0.05, 0.14, 0.18],
            [0.10, 0.22, 0.26],
            10.0,
            fin,
            0.4,
        ),
        // 3–5: crops: bare soil, young crop, grown crop
        cover(seed ^ 4, [0.30, 0.22, 0.14], [0.50, 0.40, 0.28], 2.0, fin),
        cover(seed ^ 5, [0.20, 0.32, 0.10], [0.40, 0.52, 0.22], 1.5, fin),
        cover(seed ^ 6, [0.40, 0.44, 0.12], [0.64, 0.62, 0.26], 2.5, fin),
        // 6: gravel track
        cover(seed ^ 7, [0.42, 0.40, 0.36], [0.70, 0.68, 0.62], 1.0, fin),
    ]
}

/// The land cover of an epoch at a grid position, across the corridor: water up to the day's
/// water line, sand, the band of dune grass, then fields behind the dunes, each with its own
/// crop calendar; with [`Layout::Tracks`], gravel tracks between the fields.
fn cover_by_epoch(
    seed: u64,
    layout: Layout,
) -> impl Fn(usize, f64, f64) -> usize + Send + Sync + 'static {
    let [a, b] = FIELD_EDGES;
    let fields = [(0.0, a), (a, b), (b, LENGTH + 1.0)];
    let edge = Noise::new(seed ^ 82);
    move |e: usize, x: f64, y: f64| -> usize {
        let water_line =
            BEACH_FOOT + [0.0, 4.0, -3.0][e % 3] + 1.5 * edge.fbm2(x, 0.0, 20.0, 3, 0.5);
        if y < water_line {
            return 2;
        }
        if y < BEACH_TOP {
            return 1;
        }
        if y < BAND_TOP + 2.0 * edge.fbm2(x, 5.0, 15.0, 3, 0.5) {
            return 0;
        }
        if layout == Layout::Tracks && FIELD_EDGES.iter().any(|t| (x - t).abs() < TRACK_HALF_WIDTH)
        {
            return 6;
        }
        let field = fields
            .iter()
            .position(|(a, b)| x >= *a && x < *b)
            .unwrap_or(0);
        3 + (e + field) % 3
    }
}

/// The epochs: the same drone camera (of `w` × `h` pixels) flying two strips along the
/// corridor every month, at `altitude` at the small scale.
fn monthly_epochs(
    scale: Scale,
    (w, h): (u32, u32),
    altitude: f64,
    rng: &mut SeededRng,
) -> Vec<EpochSpec> {
    let camera_seed = rng.next_u64();
    let flight = match scale {
        Scale::Small => nadir((15.0, 30.0), (285.0, 95.0), altitude, 1.5, (0.7, 0.3), 0.5),
        Scale::Full => nadir((5.0, 10.0), (295.0, 105.0), 45.0, 1.5, (0.8, 0.6), 0.5),
    };
    let names = ["2024-05-02", "2024-06-04", "2024-07-03"];
    (0..EPOCHS)
        .map(|e| {
            let camera = drone_camera(w, h, camera_seed);
            let poses = flight.poses(&camera, rng);
            let light = sun(
                (140.0 + 20.0 * e as f64).to_radians(),
                (58.0 - 4.0 * e as f64).to_radians(),
            );
            drone_epoch(names[e], camera, poses, light, rng)
        })
        .collect()
}
