//! `archival`: four panchromatic aerial surveys decades apart over farmland with a village and a
//! river (after La Peyne and Mount Rainier): film cameras of different focal lengths flown at
//! different scales, scanned with grain, dust and scratches: each image is a scan of the film
//! frame with its fiducial marks and data strip, shifted, rotated and sheared as a scanner
//! leaves it (`film`). New buildings and a road embankment
//! appear, a wood grows; there is no GNSS.

use std::sync::Arc;

use nalgebra::{Vector2, Vector3};
use timesift_core::{BrownCamera, SeededRng};

use super::*;
use crate::SynthError;
use crate::effects::{Channels, Effects};
use crate::film::{FilmSpec, MarkPattern};
use crate::flight::NadirBlock;
use crate::noise::Noise;
use crate::scene::{
    ChangeRegion, EpochSpec, Feature, Frame, ImageFormat, ImageSpec, PlacedBlock, SceneSpec, Shape,
};
use crate::shapes::{Block, Bump, Ridge};

const CELL: f64 = 2.0;
const RIVER: [(f64, f64); 6] = [
    (-10.0, 300.0),
    (400.0, 380.0),
    (800.0, 330.0),
    (1200.0, 420.0),
    (1600.0, 360.0),
    (2010.0, 430.0),
];
const ROAD: [(f64, f64); 4] = [
    (-10.0, 900.0),
    (700.0, 820.0),
    (1300.0, 880.0),
    (2010.0, 760.0),
];
const VILLAGE: ((f64, f64), (f64, f64)) = ((1180.0, 980.0), (1520.0, 1220.0));
const WOOD: Bump = Bump {
    centre: (520.0, 560.0),
    a: 130.0,
    b: 70.0,
    yaw: 0.3,
    height: 1.0,
    power: 2.0,
};
const EMBANKMENT: Ridge = Ridge {
    start: (250.0, 1080.0),
    end: (900.0, 1200.0),
    height: 5.0,
    top_width: 12.0,
    base_width: 32.0,
    ramp: 80.0,
};

/// South-west and north-east corners.
type Footprint = ((f64, f64), (f64, f64));

/// How the epochs after the first were recorded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum LaterEpochs {
    /// On film, scanned, as the first (`archival`).
    Film,
    /// By a digital frame camera of the same format and flight: colour, sensor noise only, no
    /// scan, no fiducial marks (`archival-mixed`: one film epoch among digital ones, whose
    /// reprojection noise is several times smaller, for the per-group outlier bound).
    Digital,
}

pub(super) fn build(scale: Scale, seed: u64, later: LaterEpochs) -> Result<SceneSpec, SynthError> {
    let mut rng = SeededRng::new(seed);
    let plots = building_plots(&mut rng);
    let natural = natural_surface(seed);
    let levels: Vec<f64> = plots
        .iter()
        .map(|(p, _, _)| natural(0.5 * (p.0.0 + p.1.0), 0.5 * (p.0.1 + p.1.1)))
        .collect();
    let base = base_with_levelled_plots(natural, &plots, levels.clone());
    let blocks = buildings_on_plots(&plots, &levels);
    let features = wood_and_embankment();
    let regions = change_regions(blocks.len());
    let (w, _) = image_size(scale, (512, 512), (3000, 3000));
    let fin = 0.5 * 1000.0 / w as f64;
    let materials = land_covers(seed, fin);
    let cover_fn = cover_by_epoch(seed);
    let epochs = survey_epochs(scale, w, later, &mut rng)?;
    let mut spec = new_scene(
        match later {
            LaterEpochs::Film => "archival",
            LaterEpochs::Digital => "archival-mixed",
        },
        "EPSG:2154",
        Vector3::new(731_500.0, 6_271_200.0, 0.0),
        Frame::Ground,
        (0.0, 0.0, CELL, 1001, 701),
        Arc::new(base),
        materials,
        Arc::new(cover_fn),
        epochs,
        seed,
    );
    spec.apron = 1200.0;
    spec.features = features;
    spec.blocks = blocks;
    spec.target_radius = 3.0;
    spec.regions = regions;
    spec.unstable = unstable_areas();
    spec.gnss = None;
    spec.survey_sigma = (0.05, 0.08);
    place_control(
        &mut spec,
        &mut rng,
        (8, 5),
        (250.0, 200.0),
        (1750.0, 1200.0),
        25.0,
        250.0,
        &[],
    );
    Ok(spec)
}

/// Building plots in the village, drawn apart from one another: (footprint, first epoch with
/// the building, building height). Levelled in every epoch, built on from some epoch on.
fn building_plots(rng: &mut SeededRng) -> Vec<(Footprint, usize, f64)> {
    let snap = |x: f64| snap_to_cell_boundary(x, CELL);
    let mut plots: Vec<(Footprint, usize, f64)> = Vec::new();
    for _ in 0..200 {
        if plots.len() == 10 {
            break;
        }
        let (w, d) = (rng.uniform_range(12.0, 30.0), rng.uniform_range(10.0, 20.0));
        let x = rng.uniform_range(VILLAGE.0.0 + 10.0, VILLAGE.1.0 - 10.0 - w);
        let y = rng.uniform_range(VILLAGE.0.1 + 10.0, VILLAGE.1.1 - 10.0 - d);
        let new = ((snap(x), snap(y)), (snap(x + w), snap(y + d)));
        let apart = plots.iter().all(|(p, _, _)| {
            new.0.0 > p.1.0 + 12.0
                || new.1.0 < p.0.0 - 12.0
                || new.0.1 > p.1.1 + 12.0
                || new.1.1 < p.0.1 - 12.0
        });
        if apart {
            plots.push((new, 1 + plots.len() % 3, rng.uniform_range(6.0, 12.0)));
        }
    }
    plots
}

/// The ground before any levelling: a gentle slope, hills and the river's valley.
fn natural_surface(seed: u64) -> impl Fn(f64, f64) -> f64 + Send + Sync + 'static {
    let noise = Noise::new(seed ^ 71);
    move |x: f64, y: f64| {
        let valley = -14.0 * (-(distance_to_polyline(&RIVER, x, y) / 90.0).powi(2)).exp();
        120.0
            + 0.01 * y
            + 35.0 * noise.fbm(x, y, 0.0, 900.0, 3, 0.5)
            + 4.0 * noise.fbm(x, y, 3.0, 90.0, 3, 0.5)
            + valley
    }
}

/// The stable surface: the natural ground with each plot (and 4 m around it) levelled at the
/// height `levels` gives it, blended into the ground over 10 m.
fn base_with_levelled_plots(
    natural: impl Fn(f64, f64) -> f64 + Send + Sync + 'static,
    plots: &[(Footprint, usize, f64)],
    levels: Vec<f64>,
) -> impl Fn(f64, f64) -> f64 + Send + Sync + 'static {
    let plot_rects: Vec<_> = plots.iter().map(|(p, _, _)| *p).collect();
    move |x: f64, y: f64| {
        let mut z = natural(x, y);
        for (p, level) in plot_rects.iter().zip(&levels) {
            let w = pad_weight(
                (p.0.0 - 4.0, p.0.1 - 4.0),
                (p.1.0 + 4.0, p.1.1 + 4.0),
                10.0,
                x,
                y,
            );
            z += w * (level - z);
        }
        z
    }
}

/// The buildings: one on each plot at its level, present from the plot's first epoch on.
fn buildings_on_plots(plots: &[(Footprint, usize, f64)], levels: &[f64]) -> Vec<PlacedBlock> {
    plots
        .iter()
        .zip(levels)
        .map(|((p, first, height), level)| PlacedBlock {
            block: Block {
                min: p.0,
                max: p.1,
                base: *level,
                top: level + height,
            },
            epochs: (*first..4).collect(),
            material: 5,
        })
        .collect()
}

/// The height changes: the wood's canopy in each epoch (features 0–3), the embankment from the
/// third epoch on (feature 4).
fn wood_and_embankment() -> Vec<Feature> {
    let mut features = Vec::new();
    // The wood: canopy 6 m high in 1971, growing 4 m a decade.
    for e in 0..4 {
        features.push(Feature {
            shape: Shape::Bump(Bump {
                height: 6.0 + 4.0 * e as f64,
                ..WOOD
            }),
            epochs: vec![e],
        });
    }
    features.push(Feature {
        shape: Shape::Ridge(EMBANKMENT),
        epochs: vec![2, 3],
    });
    features
}

/// The changed regions: the wood, the embankment and the village of `n_blocks` buildings.
fn change_regions(n_blocks: usize) -> Vec<ChangeRegion> {
    vec![
        ChangeRegion {
            name: "wood".into(),
            description: "woodland growing".into(),
            polygon: WOOD.footprint(5.0),
            features: vec![0, 1, 2, 3],
            blocks: vec![],
        },
        ChangeRegion {
            name: "embankment".into(),
            description: "road embankment built".into(),
            polygon: EMBANKMENT.footprint(5.0),
            features: vec![4],
            blocks: vec![],
        },
        ChangeRegion {
            name: "village".into(),
            description: "new buildings".into(),
            polygon: rect(VILLAGE.0, VILLAGE.1),
            features: vec![],
            blocks: (0..n_blocks).collect(),
        },
    ]
}

/// The materials, indexed as [`cover_by_epoch`] returns them: fields, wood, river, road,
/// village and embankment, roofs, two more crops.
fn land_covers(seed: u64, fin: f64) -> Vec<Material> {
    vec![
        cover(seed ^ 1, [0.30, 0.30, 0.22], [0.55, 0.52, 0.40], 60.0, fin),
        cover(seed ^ 2, [0.05, 0.10, 0.04], [0.16, 0.24, 0.10], 20.0, fin),
        cover(seed ^ 3, [0.06, 0.08, 0.10], [0.12, 0.14, 0.16], 50.0, fin),
        cover(seed ^ 4, [0.40, 0.40, 0.40], [0.55, 0.55, 0.55], 10.0, fin),
        cover(seed ^ 5, [0.50, 0.48, 0.44], [0.70, 0.68, 0.64], 20.0, fin),
        cover(seed ^ 6, [0.45, 0.30, 0.25], [0.70, 0.52, 0.45], 8.0, fin),
        cover(seed ^ 7, [0.55, 0.48, 0.30], [0.80, 0.74, 0.50], 40.0, fin),
        cover(seed ^ 8, [0.20, 0.28, 0.10], [0.40, 0.48, 0.22], 40.0, fin),
    ]
}

/// The land cover of an epoch at a grid position: river, road, embankment, wood, village, and
/// elsewhere fields whose crops change from epoch to epoch.
fn cover_by_epoch(seed: u64) -> impl Fn(usize, f64, f64) -> usize + Send + Sync + 'static {
    let (sin, cos) = 0.35f64.sin_cos();
    move |e: usize, x: f64, y: f64| -> usize {
        if distance_to_polyline(&RIVER, x, y) < 9.0 {
            return 2;
        }
        if distance_to_polyline(&ROAD, x, y) < 5.0 {
            return 3;
        }
        if e >= 2 && EMBANKMENT.value(x, y) > 0.0 {
            return 4;
        }
        if WOOD.value(x, y) > 0.0 {
            return 1;
        }
        if x > VILLAGE.0.0 && x < VILLAGE.1.0 && y > VILLAGE.0.1 && y < VILLAGE.1.1 {
            return 4;
        }
        // Fields: parcels of a rotated grid, each with its own crop in each epoch.
        let (u, v) = (cos * x + sin * y, -sin * x + cos * y);
        let (i, j) = ((u / 140.0).floor() as i64, (v / 90.0).floor() as i64);
        let r = hash01(i, j, e as u64 * 7 + seed);
        if r < 0.4 {
            0
        } else if r < 0.7 {
            6
        } else {
            7
        }
    }
}

/// The four survey epochs of `w` × `w` pixel images: film scans, or for `later` digital frames
/// after the first.
fn survey_epochs(
    scale: Scale,
    w: u32,
    later: LaterEpochs,
    rng: &mut SeededRng,
) -> Result<Vec<EpochSpec>, SynthError> {
    // Film cameras: (focal length mm, scale number, scan shrinks/affinity) per epoch.
    let cameras = [
        (152.0, 5500.0),
        (210.0, 5000.0),
        (152.0, 4200.0),
        (153.0, 4600.0),
    ];
    let names = ["1971-06-14", "1981-07-02", "1996-08-21", "2010-06-30"];
    // Each camera's marks: RC-type, RMK-type, crosses, dots in circles.
    let patterns = [
        MarkPattern::RcType,
        MarkPattern::RmkType,
        MarkPattern::Cross,
        MarkPattern::DotInCircle,
    ];
    let mut epochs = Vec::new();
    for (e, (f_mm, scale_number)) in cameras.iter().enumerate() {
        let digital = e > 0 && later == LaterEpochs::Digital;
        let camera = survey_camera(w, *f_mm, digital, rng)?;
        let altitude = 125.0 + f_mm / 1000.0 * scale_number;
        let images = film_era_flight(scale, altitude)
            .poses(&camera, rng)
            .into_iter()
            .map(|pose| ImageSpec {
                pose,
                effects: image_effects(e, digital, rng),
            })
            .collect();
        epochs.push(EpochSpec {
            name: names[e].into(),
            camera,
            images,
            sun: sun(
                (120.0 + 15.0 * e as f64).to_radians(),
                (50.0 + 5.0 * (e % 2) as f64).to_radians(),
            ),
            ambient: 0.35,
            shadows: true,
            supersampling: 2,
            format: ImageFormat::Tiff,
            film: (!digital).then(|| {
                FilmSpec::eight_marks(
                    &camera,
                    230.0 / w as f64,
                    patterns[e],
                    // The certificate's origin is its own, a little off the marks' centre.
                    Vector2::new(0.004 * (e as f64 + 1.0), -0.003 * e as f64),
                )
            }),
        });
    }
    Ok(epochs)
}

/// The camera of an epoch: a `f_mm` lens on a 230 mm frame imaged at `w` × `w` pixels, its
/// principal point, film deformation (none for a `digital` camera) and distortion drawn.
fn survey_camera(
    w: u32,
    f_mm: f64,
    digital: bool,
    rng: &mut SeededRng,
) -> Result<BrownCamera, SynthError> {
    let f = w as f64 * f_mm / 230.0;
    let mut camera =
        BrownCamera::new(w, w, f).map_err(|err| SynthError::InvalidScene(err.to_string()))?;
    camera.cx = 0.002 * w as f64 * rng.normal();
    camera.cy = 0.002 * w as f64 * rng.normal();
    camera.b1 = 0.0004 * f * rng.normal();
    camera.b2 = 0.0004 * f * rng.normal();
    camera.k1 = 0.004 * rng.normal();
    // Drawn for every epoch, so that the film epochs of both variants are the same.
    if digital {
        // A digital frame camera: no film deformation for b1 and b2 to stand for.
        (camera.b1, camera.b2) = (0.0, 0.0);
    }
    Ok(camera)
}

/// A film-era flight at `altitude`: more attitude and position scatter than a drone.
fn film_era_flight(scale: Scale, altitude: f64) -> NadirBlock {
    let (min, max, overlap) = match scale {
        Scale::Small => ((500.0, 450.0), (1500.0, 950.0), (0.6, 0.3)),
        Scale::Full => ((250.0, 250.0), (1750.0, 1150.0), (0.8, 0.6)),
    };
    NadirBlock {
        tilt_sigma: 0.03,
        ..nadir(min, max, altitude, 125.0, overlap, 10.0)
    }
}

/// The effects of one image of epoch `e`: a film scan's (grain, dust, scratches), or for a
/// `digital` epoch a digital camera's, drawn the same way either way.
fn image_effects(e: usize, digital: bool, rng: &mut SeededRng) -> Effects {
    let film = Effects {
        exposure: 1.3 + 0.12 * rng.normal(),
        vignetting: 0.3,
        noise_sigma: 2.0,
        grain: 0.05 + 0.02 * (3 - e) as f64,
        dust_per_mp: 40.0,
        scratches: rng.below(3) as u32,
        seed: rng.next_u64(),
        channels: Channels::Grey,
    };
    if digital {
        Effects {
            exposure: 1.2,
            vignetting: 0.1,
            noise_sigma: 1.0,
            grain: 0.0,
            dust_per_mp: 0.0,
            scratches: 0,
            channels: Channels::Rgb,
            ..film
        }
    } else {
        film
    }
}

/// Everything that is not stable: the wood, the embankment, the village, the river.
fn unstable_areas() -> Vec<Vec<[f64; 2]>> {
    let mut unstable = vec![
        WOOD.footprint(20.0),
        EMBANKMENT.footprint(15.0),
        rect(
            (VILLAGE.0.0 - 5.0, VILLAGE.0.1 - 5.0),
            (VILLAGE.1.0 + 5.0, VILLAGE.1.1 + 5.0),
        ),
    ];
    unstable.push(buffer(&RIVER, 20.0));
    unstable
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_mixed_variant_keeps_the_film_epoch_and_flies_the_others_digitally() {
        let film = build(Scale::Small, 3, LaterEpochs::Film).unwrap();
        let mixed = build(Scale::Small, 3, LaterEpochs::Digital).unwrap();
        assert_eq!(film.epochs[0], mixed.epochs[0]);
        assert!(mixed.epochs[0].film.is_some());
        for (a, b) in film.epochs.iter().zip(&mixed.epochs).skip(1) {
            assert!(b.film.is_none(), "{}", b.name);
            assert_eq!((b.camera.b1, b.camera.b2), (0.0, 0.0));
            assert_eq!((a.camera.f, a.camera.k1), (b.camera.f, b.camera.k1));
            for (x, y) in a.images.iter().zip(&b.images) {
                assert_eq!(x.pose, y.pose);
                assert_eq!(y.effects.channels, Channels::Rgb);
                assert_eq!((y.effects.grain, y.effects.dust_per_mp), (0.0, 0.0));
            }
        }
        // The same ground, control and change.
        assert_eq!(film.regions, mixed.regions);
        assert_eq!(film.gcps, mixed.gcps);
        assert_eq!(film.checkpoints, mixed.checkpoints);
    }
}
