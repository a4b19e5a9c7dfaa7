//! The seven study-case scenes of the issue, each a function of a [`Scale`] and a seed giving a
//! [`SceneSpec`]. Shared here: cameras and image effects of the platforms, land-cover palettes,
//! placement of control points on stable ground.

mod archival;
mod campus;
mod corridor;
mod glacier;
mod landslide;
mod orchard;
mod scale;
mod shore;
mod soil_pit;

use std::str::FromStr;

use nalgebra::Vector3;
use timesift_core::{BrownCamera, Pose, SeededRng};

use crate::SynthError;
use crate::effects::{Channels, Effects};
use crate::flight::NadirBlock;
use crate::noise::Noise;
pub(crate) use crate::noise::hash01;
use crate::render::{Material, Rgb};
use crate::scene::{
    BaseFn, CoverFn, EpochSpec, Frame, GnssSpec, ImageFormat, ImageSpec, NamedPoint, SceneSpec,
};

/// Size of a generated scene.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scale {
    /// For tests: at most about 60 images of at most 0.5 MP, rendered in seconds.
    Small,
    /// Realistic blocks: hundreds of images of several megapixels.
    Full,
}

impl FromStr for Scale {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "small" => Ok(Scale::Small),
            "full" => Ok(Scale::Full),
            _ => Err(format!("expected \"small\" or \"full\", got \"{s}\"")),
        }
    }
}

/// The scene names, in the order of the table.
pub const SCENES: [&str; 7] = [
    "archival",
    "glacier",
    "orchard",
    "soil-pit",
    "shore",
    "campus",
    "landslide",
];

/// Scenes beyond the table, built on request only (the tests and benches that walk
/// [`SCENES`] leave them out): `corridor`, a coastal corridor flown along its axis, where a roll
/// about the axis shows only in the DEMs; `corridor-tracks`, the same with stable ground that
/// looks alike across its width (farm tracks) and control off the dune band; `archival-mixed`, `archival` with its later three
/// epochs taken by a digital frame camera, so one noisy film epoch sits among clean digital ones.
pub const EXTRA_SCENES: [&str; 3] = ["corridor", "corridor-tracks", "archival-mixed"];
/// Scenes for benchmarks only, whatever the scale: `landslide-12mp` (one epoch of nine
/// 4000 × 3000 images, for the dense stage at a realistic image size) and `scale-<N>` (a block
/// of N images over farmland, [`ScaleLayout`] saying how they are flown, for the scale bench).
pub const BENCH_SCENES: [&str; 2] = ["landslide-12mp", "scale-<N>"];

pub use scale::ScaleLayout;

/// The scene called `name`.
pub fn build(name: &str, scale: Scale, seed: u64) -> Result<SceneSpec, SynthError> {
    match name {
        "archival" => archival::build(scale, seed, archival::LaterEpochs::Film),
        "archival-mixed" => archival::build(scale, seed, archival::LaterEpochs::Digital),
        "glacier" => glacier::build(scale, seed),
        "orchard" => orchard::build(scale, seed),
        "soil-pit" => soil_pit::build(scale, seed),
        "shore" => shore::build(scale, seed),
        "campus" => campus::build(scale, seed),
        "landslide" => landslide::build(scale, seed),
        "landslide-12mp" => landslide::build_12mp(seed),
        _ if name.starts_with("scale-") => match name["scale-".len()..].parse::<usize>() {
            Ok(n) => scale::build(n, seed),
            Err(_) => Err(SynthError::InvalidScene(format!(
                "\"{name}\": expected scale-<N>, N a number of images"
            ))),
        },
        "corridor" => corridor::build(scale, seed, corridor::Layout::Band),
        "corridor-tracks" => corridor::build(scale, seed, corridor::Layout::Tracks),
        _ => Err(SynthError::InvalidScene(format!(
            "unknown scene \"{name}\"; expected one of {}, or {}, or {}",
            SCENES.join(", "),
            EXTRA_SCENES.join(", "),
            BENCH_SCENES.join(", ")
        ))),
    }
}

/// A land cover: two colours mixed by fractal noise from `scale` metres down to `finest` (half
/// the ground sampling distance: finer detail would be averaged away within a pixel).
pub(crate) fn cover(
    seed: u64,
    dark: [f64; 3],
    light: [f64; 3],
    scale: f64,
    finest: f64,
) -> Material {
    cover_with_contrast(seed, dark, light, scale, finest, 1.3)
}

/// Strength of a cover's speckles per unit of contrast: stones, tufts and leaves a few pixels
/// across, as real ground shows and as feature detectors need (fBm alone left the small scenes
/// with almost no SIFT keypoints).
const SPECKLE_PER_CONTRAST: f64 = 0.35;

/// [`cover`] with a given contrast (low for snow and water).
pub(crate) fn cover_with_contrast(
    seed: u64,
    dark: [f64; 3],
    light: [f64; 3],
    scale: f64,
    finest: f64,
    contrast: f64,
) -> Material {
    let octaves = ((scale / finest).log2().ceil().max(0.0) as u32 + 1).clamp(1, 12);
    Material::Cover {
        noise: Box::new(Noise::new(seed)),
        dark: Rgb::new(dark[0], dark[1], dark[2]),
        light: Rgb::new(light[0], light[1], light[2]),
        scale,
        octaves,
        contrast,
        speckle: SPECKLE_PER_CONTRAST * contrast,
        speckle_seed: seed ^ 0x05be_c1e5,
    }
}

/// Half the ground sampling distance of a camera of focal length `f` pixels at `range` metres.
pub(crate) fn finest(f: f64, range: f64) -> f64 {
    0.5 * range / f
}

/// A drone camera (about 84° diagonal field of view) of `width` × `height` pixels with the
/// distortion of a typical small-format lens, varied a little by `seed`.
pub(crate) fn drone_camera(width: u32, height: u32, seed: u64) -> BrownCamera {
    let mut rng = SeededRng::new(seed);
    let f = 0.72 * width as f64 * (1.0 + 0.01 * rng.normal());
    let mut c = BrownCamera {
        width,
        height,
        f,
        cx: 0.004 * width as f64 * rng.normal(),
        cy: 0.004 * width as f64 * rng.normal(),
        b1: 0.0,
        b2: 0.0,
        k1: -0.09 + 0.01 * rng.normal(),
        k2: 0.06,
        k3: -0.015,
        k4: 0.0,
        p1: 0.0004 * rng.normal(),
        p2: 0.0004 * rng.normal(),
    };
    c.k1 = c.k1.clamp(-0.12, -0.06);
    c
}

/// Effects of a digital camera image: small exposure changes, vignetting, sensor noise.
pub(crate) fn digital_effects(rng: &mut SeededRng) -> Effects {
    Effects {
        exposure: 1.15 + 0.05 * rng.normal(),
        vignetting: 0.18,
        noise_sigma: 1.5,
        seed: rng.next_u64(),
        channels: Channels::Rgb,
        ..Effects::default()
    }
}

/// A consumer GNSS receiver on a drone or a phone.
pub(crate) const CONSUMER_GNSS: GnssSpec = GnssSpec {
    bias_h: 1.5,
    bias_v: 3.0,
    noise_h: 0.5,
    noise_v: 1.0,
};

/// A nadir block flown by a small drone: 1.1° attitude scatter, `position_sigma` metres.
pub(crate) fn nadir(
    min: (f64, f64),
    max: (f64, f64),
    altitude: f64,
    ground: f64,
    (forward, side): (f64, f64),
    position_sigma: f64,
) -> NadirBlock {
    NadirBlock {
        min,
        max,
        altitude,
        ground,
        forward,
        side,
        tilt_sigma: 0.02,
        position_sigma,
    }
}

/// A drone survey epoch: the poses, each with the effects of a digital camera, JPEG images.
pub(crate) fn drone_epoch(
    name: &str,
    camera: BrownCamera,
    poses: Vec<Pose>,
    sun: Vector3<f64>,
    rng: &mut SeededRng,
) -> EpochSpec {
    EpochSpec {
        name: name.into(),
        camera,
        images: poses
            .into_iter()
            .map(|pose| ImageSpec {
                pose,
                effects: digital_effects(rng),
            })
            .collect(),
        sun,
        ambient: 0.35,
        shadows: false,
        supersampling: 2,
        format: ImageFormat::Jpeg(92),
        film: None,
    }
}

/// A scene with nothing in it yet but its surface, cover and epochs: consumer GNSS, 0.3 px
/// markers, RTK-surveyed control (1 cm, 1.5 cm), 0.5 m targets.
#[allow(clippy::too_many_arguments)]
pub(crate) fn new_scene(
    name: &str,
    crs: &str,
    origin: Vector3<f64>,
    frame: Frame,
    grid: (f64, f64, f64, usize, usize),
    base: BaseFn,
    materials: Vec<Material>,
    cover: CoverFn,
    epochs: Vec<EpochSpec>,
    seed: u64,
) -> SceneSpec {
    SceneSpec {
        name: name.into(),
        crs: crs.into(),
        origin,
        frame,
        grid,
        base,
        apron: 0.0,
        features: Vec::new(),
        blocks: Vec::new(),
        materials,
        cover,
        warp: None,
        epochs,
        gcps: Vec::new(),
        checkpoints: Vec::new(),
        scale_targets: Vec::new(),
        scale_bars: Vec::new(),
        target_radius: 0.5,
        regions: Vec::new(),
        unstable: Vec::new(),
        gnss: Some(CONSUMER_GNSS),
        marker_sigma: 0.3,
        survey_sigma: (0.01, 0.015),
        seed,
    }
}

/// Places `gcps` GCPs and `checks` check points in the rectangle on stable ground (see
/// [`place_points`]), check points at 0.6 × the GCP spacing, apart from `taken` points.
#[allow(clippy::too_many_arguments)]
pub(crate) fn place_control(
    spec: &mut SceneSpec,
    rng: &mut SeededRng,
    (gcps, checks): (usize, usize),
    min: (f64, f64),
    max: (f64, f64),
    clearance: f64,
    spacing: f64,
    taken: &[(f64, f64)],
) {
    spec.gcps = place_points(spec, rng, gcps, "GCP", min, max, clearance, spacing, taken);
    let mut taken = taken.to_vec();
    taken.extend(spec.gcps.iter().map(|p| p.at));
    spec.checkpoints = place_points(
        spec,
        rng,
        checks,
        "CHK",
        min,
        max,
        clearance,
        0.6 * spacing,
        &taken,
    );
}

/// Image size for a scale: (small, full) pixel sizes.
pub(crate) fn image_size(scale: Scale, small: (u32, u32), full: (u32, u32)) -> (u32, u32) {
    match scale {
        Scale::Small => small,
        Scale::Full => full,
    }
}

/// Up to `n` points named `prefix1…` drawn in the rectangle, each on stable ground with
/// `clearance` metres of stable ground around it and `spacing` metres from the others.
#[allow(clippy::too_many_arguments)]
pub(crate) fn place_points(
    spec: &SceneSpec,
    rng: &mut SeededRng,
    n: usize,
    prefix: &str,
    min: (f64, f64),
    max: (f64, f64),
    clearance: f64,
    spacing: f64,
    taken: &[(f64, f64)],
) -> Vec<NamedPoint> {
    let mut out: Vec<NamedPoint> = Vec::new();
    let mut all: Vec<(f64, f64)> = taken.to_vec();
    for _ in 0..2000 {
        if out.len() == n {
            break;
        }
        let p = (
            rng.uniform_range(min.0, max.0),
            rng.uniform_range(min.1, max.1),
        );
        let clear = (0..12).all(|k| {
            let a = k as f64 * std::f64::consts::PI / 6.0;
            spec.is_stable(p.0 + clearance * a.cos(), p.1 + clearance * a.sin())
        }) && spec.is_stable(p.0, p.1)
            && spec
                .blocks
                .iter()
                .all(|b| !b.block.covers(p.0, p.1, clearance));
        let apart = all.iter().all(|q| (q.0 - p.0).hypot(q.1 - p.1) >= spacing);
        if clear && apart {
            all.push(p);
            out.push(NamedPoint {
                name: format!("{prefix}{}", out.len() + 1),
                at: p,
            });
        }
    }
    out
}

/// A polygon around a polyline at `half_width` (left side out, right side back).
pub(crate) fn buffer(line: &[(f64, f64)], half_width: f64) -> Vec<[f64; 2]> {
    let normal = |i: usize| {
        let (a, b) = if i + 1 < line.len() {
            (line[i], line[i + 1])
        } else {
            (line[i - 1], line[i])
        };
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let l = dx.hypot(dy);
        (-dy / l, dx / l)
    };
    let mut ring: Vec<[f64; 2]> = (0..line.len())
        .map(|i| {
            let n = normal(i);
            [line[i].0 + half_width * n.0, line[i].1 + half_width * n.1]
        })
        .collect();
    for i in (0..line.len()).rev() {
        let n = normal(i);
        ring.push([line[i].0 - half_width * n.0, line[i].1 - half_width * n.1]);
    }
    ring
}

/// Distance from a point to a polyline.
pub(crate) fn distance_to_polyline(line: &[(f64, f64)], x: f64, y: f64) -> f64 {
    line.windows(2)
        .map(|w| {
            let (a, b) = (w[0], w[1]);
            let (dx, dy) = (b.0 - a.0, b.1 - a.1);
            let t = (((x - a.0) * dx + (y - a.1) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
            let (ex, ey) = (x - a.0 - t * dx, y - a.1 - t * dy);
            ex * ex + ey * ey
        })
        .fold(f64::INFINITY, f64::min)
        .sqrt()
}

/// Unit vector towards a sun at `azimuth` (clockwise from north) and `elevation`, radians.
pub(crate) fn sun(azimuth: f64, elevation: f64) -> Vector3<f64> {
    Vector3::new(
        azimuth.sin() * elevation.cos(),
        azimuth.cos() * elevation.cos(),
        elevation.sin(),
    )
}

/// Smooth weight: 1 inside the rectangle, falling to 0 at `blend` metres outside it.
pub(crate) fn pad_weight(min: (f64, f64), max: (f64, f64), blend: f64, x: f64, y: f64) -> f64 {
    let dx = (min.0 - x).max(x - max.0).max(0.0);
    let dy = (min.1 - y).max(y - max.1).max(0.0);
    let t = (dx.hypot(dy) / blend).min(1.0);
    1.0 - t * t * (3.0 - 2.0 * t)
}

/// A rectangle as a polygon.
pub(crate) fn rect(min: (f64, f64), max: (f64, f64)) -> Vec<[f64; 2]> {
    vec![
        [min.0, min.1],
        [max.0, min.1],
        [max.0, max.1],
        [min.0, max.1],
    ]
}

/// The cell boundary nearest to `x` on a grid of nodes at multiples of `cell` (boundaries lie
/// half-way between nodes): box edges placed there make DEM cells either fully in or out.
pub(crate) fn snap_to_cell_boundary(x: f64, cell: f64) -> f64 {
    ((x / cell - 0.5).round() + 0.5) * cell
}
