//! `glacier`: a valley glacier tongue surveyed yearly by drone (after Forni and Val Veny). The ice
//! surface lowers by up to about 8 m a year and the terminus retreats; snow and ice are bright and
//! nearly textureless; the rock around is stable.

use std::sync::Arc;

use nalgebra::Vector3;
use timesift_core::SeededRng;

use super::*;
use crate::SynthError;
use crate::noise::Noise;
use crate::scene::{ChangeRegion, Feature, SceneSpec, Shape};
use crate::shapes::Bump;

/// The ice body of epoch `e`: shorter and thinner every year.
fn ice(e: usize) -> Bump {
    let e = e as f64;
    Bump {
        centre: (470.0 + 22.0 * e, 300.0),
        a: 320.0 - 22.0 * e,
        b: 140.0 - 3.0 * e,
        yaw: 0.0,
        height: 42.0 - 7.0 * e,
        power: 2.0,
    }
}

pub(super) fn build(scale: Scale, seed: u64) -> Result<SceneSpec, SynthError> {
    let mut rng = SeededRng::new(seed);
    let noise = Noise::new(seed ^ 21);
    let base = move |x: f64, y: f64| {
        0.12 * x
            + 0.0008 * (y - 300.0).powi(2)
            + 6.0 * noise.fbm(x, y, 0.0, 120.0, 4, 0.5)
            + 0.8 * noise.fbm(x, y, 7.0, 10.0, 3, 0.5)
    };
    let n_epochs = 3;
    let features: Vec<Feature> = (0..n_epochs)
        .map(|e| Feature {
            shape: Shape::Bump(ice(e)),
            epochs: vec![e],
        })
        .collect();
    let (w, h) = image_size(scale, (512, 384), (3000, 2000));
    let f = 0.72 * w as f64;
    let fin = finest(f, 190.0);
    let materials = vec![
        cover(seed ^ 1, [0.26, 0.24, 0.22], [0.58, 0.55, 0.50], 60.0, fin),
        cover_with_contrast(
            seed ^ 2,
            [0.80, 0.84, 0.90],
            [0.93, 0.95, 0.98],
            40.0,
            fin,
            0.45,
        ),
        cover(seed ^ 3, [0.40, 0.38, 0.36], [0.75, 0.75, 0.76], 15.0, fin),
    ];
    let cover_fn = move |e: usize, x: f64, y: f64| -> usize {
        let thickness = ice(e).value(x, y);
        if thickness > 3.0 {
            1
        } else if thickness > 0.0 {
            2 // dirty ice and moraine at the margin
        } else {
            0
        }
    };
    let camera_seed = rng.next_u64();
    let flight = match scale {
        Scale::Small => nadir((150.0, 150.0), (650.0, 450.0), 260.0, 70.0, (0.5, 0.4), 2.0),
        Scale::Full => nadir((80.0, 80.0), (720.0, 520.0), 260.0, 70.0, (0.8, 0.7), 2.0),
    };
    let names = ["2021-09-10", "2022-09-08", "2023-09-12"];
    let epochs = (0..n_epochs)
        .map(|e| {
            let camera = drone_camera(w, h, camera_seed);
            let poses = flight.poses(&camera, &mut rng);
            let light = sun((150.0 + 8.0 * e as f64).to_radians(), 38f64.to_radians());
            let mut epoch = drone_epoch(names[e], camera, poses, light, &mut rng);
            epoch.ambient = 0.4;
            epoch
        })
        .collect();
    let mut spec = new_scene(
        "glacier",
        "EPSG:32632",
        Vector3::new(621_400.0, 5_140_200.0, 2450.0),
        Frame::Ground,
        (0.0, 0.0, 1.0, 801, 601),
        Arc::new(base),
        materials,
        Arc::new(cover_fn),
        epochs,
        seed,
    );
    spec.apron = 300.0;
    spec.features = features;
    spec.target_radius = 1.0;
    spec.regions = vec![ChangeRegion {
        name: "glacier".into(),
        description: "ice surface lowering and terminus retreat".into(),
        polygon: ice(0).footprint(5.0),
        features: (0..n_epochs).collect(),
        blocks: vec![],
    }];
    spec.unstable = vec![ice(0).footprint(15.0)];
    spec.survey_sigma = (0.02, 0.03);
    place_control(
        &mut spec,
        &mut rng,
        (6, 4),
        (60.0, 95.0),
        (740.0, 505.0),
        10.0,
        110.0,
        &[],
    );
    Ok(spec)
}
