//! `scale-<N>`: a Time-SIFT block of N images for the scale bench (`cargo xtask bench scale`):
//! rolling farmland flown by a drone with consumer GNSS, epoch after epoch, with control in
//! every epoch's images. Blocks grow as archives do: by more epochs and a larger area, never by
//! denser images, so the cost per image stays comparable from N to N.
//!
//! Between epochs, fields change their crop (their texture, not their height) and mounds of
//! spoil appear and stay (height); both are outside the stable ground. Everything else
//! (meadow, woods, tracks) is stable.

use std::sync::Arc;

use nalgebra::Vector3;
use timesift_core::{Pose, SeededRng};

use super::*;
use crate::SynthError;
use crate::flight::{jitter, nadir_rotation};
use crate::scene::{Feature, SceneSpec, Shape};
use crate::shapes::Bump;

/// Image size: small, so that 1,600 images render in minutes.
const IMAGE: (u32, u32) = (480, 360);
/// Flying height above the ground, metres (GSD about 0.3 m).
const RANGE: f64 = 105.0;
/// Forward and side overlap.
const OVERLAP: (f64, f64) = (0.7, 0.6);
/// Side of a land parcel (field, meadow or wood), metres.
const PARCEL: f64 = 40.0;
/// Width of the meadow strip (hedgerow, track) inside a parcel's edge around a field or wood.
const HEDGE: f64 = 4.0;
/// Share of the parcels that are fields (their crop changes every epoch).
const FIELD_SHARE: f64 = 0.3;
/// Share of the parcels that are woods.
const WOOD_SHARE: f64 = 0.15;
/// Ground cell of the truth, metres.
const CELL: f64 = 0.5;

/// How N images are flown: `epochs` epochs of `nx` × `ny` images each.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScaleLayout {
    /// Epochs.
    pub epochs: usize,
    /// Images per strip.
    pub nx: usize,
    /// Strips.
    pub ny: usize,
}

impl ScaleLayout {
    /// The layout of a block of `n` images: 4 epochs up to 200 images, the epochs doubling when
    /// N quadruples (8 at 400 and 800, 16 at 1,600), the rest an area of N / epochs images
    /// per epoch, as square as the count allows. `n` is rounded to what the layout holds.
    pub fn of(n: usize) -> Result<ScaleLayout, SynthError> {
        if !(20..=20_000).contains(&n) {
            return Err(SynthError::InvalidScene(format!(
                "scale-{n}: expected between 20 and 20000 images"
            )));
        }
        let doublings = ((n as f64 / 100.0).log2().max(0.0) / 2.0).floor() as u32;
        let epochs = 4usize << doublings;
        let per_epoch = (n / epochs).max(4);
        // The largest divisor not above the square root: a rectangle of exactly per_epoch.
        let ny = (1..=per_epoch)
            .take_while(|d| d * d <= per_epoch)
            .filter(|d| per_epoch % d == 0)
            .last()
            .unwrap_or(1);
        let (nx, ny) = if ny >= 3 || per_epoch < 9 {
            (per_epoch / ny, ny)
        } else {
            // A prime count would fly one long strip: round down to a rectangle instead.
            let s = (per_epoch as f64).sqrt().floor() as usize;
            (per_epoch / s, s)
        };
        Ok(ScaleLayout { epochs, nx, ny })
    }

    /// Images in the block.
    pub fn images(&self) -> usize {
        self.epochs * self.nx * self.ny
    }
}

/// The scene `scale-<n>`.
pub(super) fn build(n: usize, seed: u64) -> Result<SceneSpec, SynthError> {
    let layout = ScaleLayout::of(n)?;
    let mut rng = SeededRng::new(seed);
    let (w, h) = IMAGE;
    let camera = drone_camera(w, h, rng.next_u64());
    let f = 0.72 * w as f64;
    let along = RANGE * w as f64 / f * (1.0 - OVERLAP.0);
    let across = RANGE * h as f64 / f * (1.0 - OVERLAP.1);
    // The flown area, and the ground the outer images see beyond it.
    let margin = (0.6 * RANGE * w as f64 / f).ceil();
    let (lx, ly) = (
        (layout.nx - 1) as f64 * along,
        (layout.ny - 1) as f64 * across,
    );
    let nodes = |l: f64| ((l + 2.0 * margin) / CELL).ceil() as usize + 1;
    let grid = (-margin, -margin, CELL, nodes(lx), nodes(ly));
    let fin = finest(f, RANGE);
    let base = farmland(seed);
    let ground = base.clone();
    let parcels = Parcels { seed };
    let mut unstable = Vec::new();
    for j in parcels.index(-margin)..=parcels.index(ly + margin) {
        for i in parcels.index(-margin)..=parcels.index(lx + margin) {
            if parcels.kind(i, j) != ParcelKind::Meadow {
                let (x0, y0) = parcels.corner(i, j);
                let edge = HEDGE - 1.0;
                unstable.push(rect(
                    (x0 + edge, y0 + edge),
                    (x0 + PARCEL - edge, y0 + PARCEL - edge),
                ));
            }
        }
    }
    // Mounds of spoil: one in about every fourth meadow parcel of the block, from the second
    // epoch on, each staying once it has come; inside its parcel, so that no two unstable
    // polygons overlap.
    let mut features = Vec::new();
    for j in parcels.index(0.0)..=parcels.index(ly) {
        for i in parcels.index(0.0)..=parcels.index(lx) {
            if parcels.kind(i, j) != ParcelKind::Meadow || rng.uniform() > 0.25 {
                continue;
            }
            let (x0, y0) = parcels.corner(i, j);
            let radius = rng.uniform_range(5.0, 9.0);
            let room = radius + 4.0;
            let centre = (
                rng.uniform_range(x0 + room, x0 + PARCEL - room),
                rng.uniform_range(y0 + room, y0 + PARCEL - room),
            );
            let bump = Bump::round(centre, radius, rng.uniform_range(1.0, 2.5), 2.0);
            unstable.push(bump.footprint(2.0));
            features.push(Feature {
                shape: Shape::Bump(bump),
                epochs: (1 + features.len() % (layout.epochs - 1)..layout.epochs).collect(),
            });
        }
    }
    let epochs = (0..layout.epochs)
        .map(|e| {
            let poses = grid_poses(&layout, (along, across), &ground, &mut rng);
            let light = sun(
                (150.0 + 5.0 * (e % 5) as f64).to_radians(),
                (55.0 - 4.0 * (e % 4) as f64).to_radians(),
            );
            drone_epoch(&epoch_name(e), camera, poses, light, &mut rng)
        })
        .collect();
    let materials = vec![
        cover(seed ^ 1, [0.25, 0.34, 0.12], [0.46, 0.52, 0.26], 15.0, fin),
        cover(seed ^ 2, [0.04, 0.14, 0.04], [0.14, 0.30, 0.10], 4.0, fin),
        cover(seed ^ 3, [0.40, 0.33, 0.24], [0.62, 0.54, 0.42], 8.0, fin),
        cover(seed ^ 4, [0.30, 0.40, 0.10], [0.55, 0.62, 0.22], 6.0, fin),
        cover(seed ^ 5, [0.55, 0.48, 0.20], [0.80, 0.72, 0.40], 6.0, fin),
    ];
    let cover_fn = move |e: usize, x: f64, y: f64| -> usize {
        let (i, j) = (parcels.index(x), parcels.index(y));
        match parcels.kind_at(x, y) {
            ParcelKind::Meadow => 0,
            ParcelKind::Wood => 1,
            // A field: bare soil, green crop or ripe crop, its own rotation.
            ParcelKind::Field => 2 + (e + (hash01(i, j, seed ^ 7) * 3.0) as usize) % 3,
        }
    };
    let mut spec = new_scene(
        &format!("scale-{}", layout.images()),
        "EPSG:32633",
        Vector3::new(412_300.0, 5_561_800.0, 310.0),
        Frame::Ground,
        grid,
        Arc::new(base),
        materials,
        Arc::new(cover_fn),
        epochs,
        seed,
    );
    spec.apron = 2.0 * margin;
    spec.features = features;
    spec.unstable = unstable;
    // Control about every 100 m, check points between them.
    let gcps = ((lx * ly) / 10_000.0).ceil().clamp(5.0, 40.0) as usize;
    let spacing = (lx * ly / gcps as f64).sqrt() * 0.6;
    place_control(
        &mut spec,
        &mut rng,
        (gcps, gcps),
        (0.05 * lx, 0.05 * ly),
        (0.95 * lx, 0.95 * ly),
        3.0,
        spacing,
        &[],
    );
    Ok(spec)
}

/// Epoch `e`'s name: every two months from January 2020.
fn epoch_name(e: usize) -> String {
    format!("{}-{:02}-15", 2020 + e / 6, 1 + 2 * (e % 6))
}

/// An epoch's cameras: `nx` × `ny` positions at the overlaps over the block (strips along x,
/// alternating heading), at `RANGE` above the ground under each, with a drone's scatter.
fn grid_poses(
    layout: &ScaleLayout,
    (along, across): (f64, f64),
    ground: &dyn Fn(f64, f64) -> f64,
    rng: &mut SeededRng,
) -> Vec<Pose> {
    let mut poses = Vec::with_capacity(layout.nx * layout.ny);
    for j in 0..layout.ny {
        let forward = j % 2 == 0;
        let heading = if forward { 0.0 } else { std::f64::consts::PI };
        for k in 0..layout.nx {
            let i = if forward { k } else { layout.nx - 1 - k };
            let (x, y) = (i as f64 * along, j as f64 * across);
            let c = Vector3::new(x, y, ground(x, y) + RANGE);
            let pose = Pose::from_rotation_and_center(nadir_rotation(heading), &c);
            poses.push(jitter(&pose, 0.02, 1.0, rng));
        }
    }
    poses
}

/// What a parcel is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ParcelKind {
    Meadow,
    Wood,
    Field,
}

/// The square parcels of the farmland, each drawn from the seed.
#[derive(Debug, Clone, Copy)]
struct Parcels {
    seed: u64,
}

impl Parcels {
    fn index(&self, v: f64) -> i64 {
        (v / PARCEL).floor() as i64
    }

    fn corner(&self, i: i64, j: i64) -> (f64, f64) {
        (i as f64 * PARCEL, j as f64 * PARCEL)
    }

    /// The parcel's kind; a field or wood leaves a meadow strip `HEDGE` wide inside its edge.
    fn kind_at(&self, x: f64, y: f64) -> ParcelKind {
        let (i, j) = (self.index(x), self.index(y));
        let (x0, y0) = self.corner(i, j);
        let inside = (x - x0)
            .min(x0 + PARCEL - x)
            .min(y - y0)
            .min(y0 + PARCEL - y);
        if inside < HEDGE {
            ParcelKind::Meadow
        } else {
            self.kind(i, j)
        }
    }

    fn kind(&self, i: i64, j: i64) -> ParcelKind {
        let u = hash01(i, j, self.seed ^ 0x5ca1e);
        if u < FIELD_SHARE {
            ParcelKind::Field
        } else if u < FIELD_SHARE + WOOD_SHARE {
            ParcelKind::Wood
        } else {
            ParcelKind::Meadow
        }
    }
}

/// The stable surface: gentle rolling farmland with rough detail.
fn farmland(seed: u64) -> impl Fn(f64, f64) -> f64 + Send + Sync + Clone + 'static {
    let noise = Arc::new(crate::noise::Noise::new(seed ^ 71));
    move |x: f64, y: f64| {
        0.02 * x
            + 8.0 * noise.fbm(x, y, 0.0, 150.0, 4, 0.5)
            + 0.5 * noise.fbm(x, y, 5.0, 8.0, 3, 0.5)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_layouts_of_the_bench_sizes_hold_exactly_n_images_in_more_epochs_and_a_larger_area() {
        let expected = [
            (100, (4, 5, 5)),
            (200, (4, 10, 5)),
            (400, (8, 10, 5)),
            (800, (8, 10, 10)),
            (1600, (16, 10, 10)),
        ];
        for (n, (epochs, nx, ny)) in expected {
            let layout = ScaleLayout::of(n).unwrap();
            assert_eq!(layout, ScaleLayout { epochs, nx, ny }, "N = {n}");
            assert_eq!(layout.images(), n);
        }
        assert!(ScaleLayout::of(5).is_err());
    }
}
