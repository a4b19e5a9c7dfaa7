//! `soil-pit`: a vertical soil wall photographed from close range before and after five samples
//! of known volume (100–1400 cm³) are dug out of it, half an hour apart, for bulk density. Four
//! scale bars of known length are pinned to the wall; control and check points are total-station
//! targets on it.

use std::f64::consts::PI;
use std::sync::Arc;

use nalgebra::Vector3;
use timesift_core::{BrownCamera, Pose, SeededRng};

use super::*;
use crate::SynthError;
use crate::flight::jitter;
use crate::noise::Noise;
use crate::scene::{
    ChangeRegion, EpochSpec, Feature, Frame, GnssSpec, ImageFormat, ImageSpec, NamedPoint,
    ScaleBar, SceneSpec, Shape,
};
use crate::shapes::Bump;

/// Sample volumes, m³ (100, 300, 600, 1000 and 1400 cm³).
const VOLUMES: [f64; 5] = [100e-6, 300e-6, 600e-6, 1000e-6, 1400e-6];
const WIDTH: f64 = 1.6;
const HEIGHT: f64 = 1.2;

pub(super) fn build(scale: Scale, seed: u64) -> Result<SceneSpec, SynthError> {
    let mut rng = SeededRng::new(seed);
    let noise = Noise::new(seed ^ 41);
    let base = move |x: f64, y: f64| {
        0.012 * noise.fbm(x, y, 0.0, 0.35, 4, 0.5) + 0.003 * noise.fbm(x, y, 3.0, 0.04, 3, 0.5)
    };
    let Pits {
        features,
        regions,
        unstable,
    } = sample_pits();
    let (w, h) = image_size(scale, (512, 384), (3000, 2000));
    let fin = 0.5 * 1.2 / (0.8 * w as f64);
    let materials = vec![
        cover(seed ^ 1, [0.12, 0.09, 0.07], [0.30, 0.23, 0.17], 0.15, fin),
        cover(seed ^ 2, [0.36, 0.24, 0.14], [0.58, 0.42, 0.27], 0.15, fin),
        cover(seed ^ 3, [0.55, 0.42, 0.22], [0.78, 0.64, 0.40], 0.15, fin),
        cover(seed ^ 4, [0.45, 0.40, 0.36], [0.66, 0.61, 0.56], 0.10, fin),
    ];
    let cover_fn = soil_horizons(seed);
    let camera = phone_camera(w, h)?;
    let epochs = convergent_epochs(scale, camera, &mut rng);
    let mut spec = new_scene(
        "soil-pit",
        "EPSG:32631",
        Vector3::new(561_240.0, 4_838_710.0, 118.0),
        Frame::Wall,
        (0.0, 0.0, 0.0025, 641, 481),
        Arc::new(base),
        materials,
        Arc::new(cover_fn),
        epochs,
        seed,
    );
    spec.apron = 1.0;
    spec.features = features;
    spec.target_radius = 0.008;
    spec.regions = regions;
    spec.unstable = unstable;
    // A phone's GNSS: worse than a drone's.
    spec.gnss = Some(GnssSpec {
        bias_h: 3.0,
        bias_v: 5.0,
        noise_h: 1.0,
        noise_v: 2.0,
    });
    spec.survey_sigma = (0.001, 0.001);
    pin_scale_bars(&mut spec);
    place_wall_control(&mut spec, &mut rng);
    Ok(spec)
}

/// The sample pits dug out of the wall: their height changes (present in the second epoch), a
/// changed region and an unstable polygon each.
struct Pits {
    features: Vec<Feature>,
    regions: Vec<ChangeRegion>,
    unstable: Vec<Vec<[f64; 2]>>,
}

/// The pits of the [`VOLUMES`], in two staggered rows: as deep as they are wide, V = π r² d / 3
/// with d = r (power-2 bumps).
fn sample_pits() -> Pits {
    let mut features = Vec::new();
    let mut regions = Vec::new();
    let mut unstable = Vec::new();
    for (k, v) in VOLUMES.iter().enumerate() {
        let r = (3.0 * v / PI).cbrt();
        let centre = (0.25 + 0.29 * k as f64, if k % 2 == 0 { 0.42 } else { 0.74 });
        let pit = Bump::round(centre, r, -r, 2.0);
        regions.push(ChangeRegion {
            name: format!("sample-{}", k + 1),
            description: format!("sample of {:.0} cm³ dug out", v * 1e6),
            polygon: pit.footprint(0.005),
            features: vec![features.len()],
            blocks: vec![],
        });
        unstable.push(pit.footprint(0.015));
        features.push(Feature {
            shape: Shape::Bump(pit),
            epochs: vec![1],
        });
    }
    Pits {
        features,
        regions,
        unstable,
    }
}

/// The cover at a wall position: the soil horizons, their boundaries wobbling, and the pit's
/// far rim above the wall.
fn soil_horizons(seed: u64) -> impl Fn(usize, f64, f64) -> usize + Send + Sync + 'static {
    let horizon_noise = Noise::new(seed ^ 42);
    move |_e: usize, x: f64, y: f64| -> usize {
        let wobble = 0.05 * horizon_noise.fbm(x, 0.0, 0.0, 0.5, 3, 0.5);
        let depth = HEIGHT - y + wobble;
        if y > HEIGHT + 0.02 {
            3 // above the pit: the pit's far rim, grass and stones
        } else if depth < 0.3 {
            0 // A horizon: dark topsoil
        } else if depth < 0.75 {
            1 // B horizon
        } else {
            2 // C horizon
        }
    }
}

/// A phone camera of `w` × `h` pixels with a slightly wide lens and mild distortion.
fn phone_camera(w: u32, h: u32) -> Result<BrownCamera, SynthError> {
    let mut c = BrownCamera::new(w, h, 0.8 * w as f64)
        .map_err(|e| SynthError::InvalidScene(e.to_string()))?;
    c.cx = 0.003 * w as f64;
    c.cy = -0.002 * w as f64;
    c.k1 = -0.06;
    c.k2 = 0.03;
    c.p1 = 0.0003;
    Ok(c)
}

/// The two epochs, before and after the digging: convergent stations on arcs 1.1–1.5 m from
/// the wall, at two or three heights.
fn convergent_epochs(scale: Scale, camera: BrownCamera, rng: &mut SeededRng) -> Vec<EpochSpec> {
    let (columns, heights): (usize, &[f64]) = match scale {
        Scale::Small => (8, &[0.35, 0.9]),
        Scale::Full => (20, &[0.25, 0.6, 0.95]),
    };
    (0..2)
        .map(|e| {
            let mut images = Vec::new();
            for &z in heights {
                for c in 0..columns {
                    let t = c as f64 / (columns - 1) as f64;
                    let x = -0.25 + (WIDTH + 0.5) * t;
                    let distance = 1.25 + 0.1 * (2.0 * PI * t).sin();
                    let target = Vector3::new(0.35 + 0.9 * t, 0.0, 0.45 + 0.3 * (z - 0.35));
                    if let Some(pose) = Pose::look_at(&Vector3::new(x, distance, z), &target) {
                        images.push(ImageSpec {
                            pose: jitter(&pose, 0.01, 0.01, rng),
                            effects: digital_effects(rng),
                        });
                    }
                }
            }
            EpochSpec {
                name: ["2025-05-20_1000", "2025-05-20_1030"][e].into(),
                camera,
                images,
                sun: sun(0.0, 55f64.to_radians()) + Vector3::new(0.0, 0.0, 0.0),
                ambient: 0.55,
                shadows: false,
                supersampling: 2,
                format: ImageFormat::Jpeg(95),
                film: None,
            }
        })
        .collect()
}

/// Pins the four scale bars to the wall: their targets `SBka`, `SBkb` and the bars.
fn pin_scale_bars(spec: &mut SceneSpec) {
    let bars = [
        ((0.08, 0.08), (0.68, 0.08)),
        ((0.92, 0.08), (1.52, 0.08)),
        ((0.06, 0.50), (0.06, 1.10)),
        ((1.54, 0.50), (1.54, 1.10)),
    ];
    for (k, (a, b)) in bars.iter().enumerate() {
        let (na, nb) = (format!("SB{}a", k + 1), format!("SB{}b", k + 1));
        spec.scale_targets.push(NamedPoint {
            name: na.clone(),
            at: *a,
        });
        spec.scale_targets.push(NamedPoint {
            name: nb.clone(),
            at: *b,
        });
        spec.scale_bars.push(ScaleBar { a: na, b: nb });
    }
}

/// Places four GCPs and three check points on the wall, apart from the scale-bar targets and
/// from one another.
fn place_wall_control(spec: &mut SceneSpec, rng: &mut SeededRng) {
    let taken: Vec<_> = spec.scale_targets.iter().map(|p| p.at).collect();
    spec.gcps = place_points(
        spec,
        rng,
        4,
        "GCP",
        (0.15, 0.15),
        (1.45, 1.1),
        0.03,
        0.35,
        &taken,
    );
    let mut taken = taken;
    taken.extend(spec.gcps.iter().map(|p| p.at));
    spec.checkpoints = place_points(
        spec,
        rng,
        3,
        "CHK",
        (0.15, 0.15),
        (1.45, 1.1),
        0.03,
        0.25,
        &taken,
    );
}
