//! Ground that changed between epochs, found from a single block itself when the caller knows no
//! stable areas (in the spirit of py4dgeo's stable-area selection for ICP).
//!
//! Why a regional test: a surface that changed smoothly by a few decimetres (accreting sand,
//! thinning ice, a creeping slope) keeps its texture, so its features match across epochs, and
//! each such tie point misses its epochs by less than the noise: the moved-point test cannot see
//! it, and the block bends to give the point one position, flattening exactly the change users
//! look for. Intersected separately in each epoch with the block's poses, these points still
//! differ by part of the change; one point's difference is lost in its noise, but the weighted
//! mean of the few dozen ties of a region is not. Regions whose mean difference is significant
//! (4 σ of its standard error, the σ inflated by the spread of all ties) are taken as changed,
//! the strongest first: a round takes those within half the strongest significance, the block
//! is adjusted without their ties (which relaxes the bending around them), and the next round
//! looks again, so that the bending never passes for change. When more than half
//! of the tested regions look changed the block as a whole is deformed (or the epochs hardly
//! overlap), and nothing is taken: dropping most ties would leave the epochs untied.

use std::collections::BTreeMap;

use nalgebra::Vector3;
use timesift_geometry::triangulation::{PixelObservation, intersect_weighted};

use crate::model::{Reconstruction, SfmInput};
use crate::robust::median_abs_deviation;
use crate::stable_ground::StableGround;

/// Significance of a region's mean difference that marks it changed.
const CHANGED_Z: f64 = 4.0;
/// Share of the round's strongest significance a region needs to be taken in this round.
const PEEL: f64 = 0.5;
/// Ties a region needs to be tested.
const MIN_TIES_PER_REGION: usize = 5;
/// Ties a region holds on average: the region's size follows from it.
const TIES_PER_REGION: f64 = 25.0;
/// Fewest ties before any region is tested.
const MIN_TIES: usize = 30;

/// A region's column and row.
type Cell = (usize, usize);

/// One inter-epoch tie point intersected in two epochs.
#[derive(Debug, Clone, Copy)]
struct TieDifference {
    /// Horizontal position (the block's position of the point).
    xy: [f64; 2],
    /// Epoch pair (base, other).
    pair: (usize, usize),
    /// Other − base position.
    difference: Vector3<f64>,
    /// Variance of each component of the difference, m².
    variance: Vector3<f64>,
}

/// What [`detect_changed_ground`] found.
#[derive(Debug, Clone)]
pub(crate) struct Detection {
    /// Everything but the changed regions.
    pub stable: StableGround,
    /// Regions taken as changed.
    pub regions_changed: usize,
}

/// The inter-epoch tie points of `rec` (georeferenced, z up), each intersected in every epoch that
/// observes it at least twice, compared region by region. `noise_px` is the σ of one
/// observation. `None` when too few ties can be tested or the block looks deformed as a whole.
pub(crate) fn detect_changed_ground(
    input: &SfmInput,
    rec: &Reconstruction,
    epoch_of: &[usize],
    reference: usize,
    noise_px: f64,
) -> Option<Detection> {
    let ties = tie_differences(input, rec, epoch_of, reference, noise_px);
    if ties.len() < MIN_TIES {
        tracing::info!(
            ties = ties.len(),
            "too few inter-epoch ties intersected in two epochs to look for changed ground"
        );
        return None;
    }
    let inflation = inflation_of(&ties);
    let (lo, hi) = ties.iter().fold(
        ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]),
        |(lo, hi), t| {
            (
                [lo[0].min(t.xy[0]), lo[1].min(t.xy[1])],
                [hi[0].max(t.xy[0]), hi[1].max(t.xy[1])],
            )
        },
    );
    let area = ((hi[0] - lo[0]) * (hi[1] - lo[1])).max(f64::MIN_POSITIVE);
    let cell = (area * TIES_PER_REGION / ties.len() as f64).sqrt();
    if !(cell > 0.0) || !cell.is_finite() {
        return None;
    }
    let width = ((hi[0] - lo[0]) / cell).floor() as usize + 1;
    let height = ((hi[1] - lo[1]) / cell).floor() as usize + 1;
    let significance = region_significance(&ties, lo, cell, [width, height], inflation);
    // The most significant regions only: around a changed region the block is bent, and its
    // neighbours differ too until an adjustment without the changed region's ties relaxes them;
    // the next round then sees what is left.
    let strongest = significance.values().copied().fold(0.0, f64::max);
    let threshold = CHANGED_Z.max(PEEL * strongest);
    let changed: Vec<(usize, usize)> = significance
        .iter()
        .filter(|(_, z)| **z > threshold)
        .map(|(r, _)| *r)
        .collect();
    let core = significance.values().filter(|z| **z > CHANGED_Z).count();
    let tested = significance.len();
    tracing::info!(
        ties = ties.len(),
        region_m = cell,
        inflation,
        tested,
        changed = changed.len(),
        "changed ground from the inter-epoch ties"
    );
    if core * 2 > tested {
        tracing::warn!(
            tested,
            changed = core,
            "most regions of the block differ between epochs: taken as a deformation of the block, \
             not as changed ground; every tie kept"
        );
        return None;
    }
    let stable = stable_grid(rec, (lo, hi), cell, &changed)?;
    if changed.is_empty() {
        return None;
    }
    Some(Detection {
        stable,
        regions_changed: changed.len(),
    })
}

/// How much the spread of all normalised differences inflates the formal σ (never deflates
/// it): a block's σ from the reprojection noise alone misses its systematic errors.
fn inflation_of(ties: &[TieDifference]) -> f64 {
    let mut normalised: Vec<f64> = ties
        .iter()
        .flat_map(|t| (0..3).map(move |k| t.difference[k] / t.variance[k].sqrt()))
        .filter(|v| v.is_finite())
        .collect();
    (1.4826 * median_abs_deviation(&mut normalised)).max(1.0)
}

/// Per region (cells of `cell` metres from `lo`, `size` columns and rows), the largest
/// significance of its ties' weighted mean difference over its epoch pairs.
fn region_significance(
    ties: &[TieDifference],
    lo: [f64; 2],
    cell: f64,
    [width, height]: [usize; 2],
    inflation: f64,
) -> BTreeMap<Cell, f64> {
    let cell_of = |xy: [f64; 2]| {
        let col = (((xy[0] - lo[0]) / cell).floor() as usize).min(width - 1);
        let row = (((xy[1] - lo[1]) / cell).floor() as usize).min(height - 1);
        (col, row)
    };
    // Per region and epoch pair: inverse-variance weighted mean of each component.
    let mut sums: BTreeMap<(Cell, (usize, usize)), Region> = BTreeMap::new();
    for t in ties {
        sums.entry((cell_of(t.xy), t.pair))
            .or_default()
            .add(&t.difference, &t.variance);
    }
    // Largest significance per region over its epoch pairs.
    let mut significance: BTreeMap<(usize, usize), f64> = BTreeMap::new();
    for ((region, _), sum) in &sums {
        if sum.count < MIN_TIES_PER_REGION {
            continue;
        }
        let z = sum.significance(inflation);
        let entry = significance.entry(*region).or_insert(0.0);
        *entry = entry.max(z);
    }
    significance
}

/// Stable ground on a grid covering every point of the block (outside it nothing counts as
/// stable), its cells aligned with the regions' (`lo` the regions' origin, `hi` their far
/// corner): everywhere but the `changed` regions.
fn stable_grid(
    rec: &Reconstruction,
    (lo, hi): ([f64; 2], [f64; 2]),
    cell: f64,
    changed: &[Cell],
) -> Option<StableGround> {
    let (all_lo, all_hi) = rec.points.iter().fold((lo, hi), |(lo, hi), p| {
        (
            [lo[0].min(p.position.x), lo[1].min(p.position.y)],
            [hi[0].max(p.position.x), hi[1].max(p.position.y)],
        )
    });
    let before = [
        ((lo[0] - all_lo[0]) / cell).ceil() + 1.0,
        ((lo[1] - all_lo[1]) / cell).ceil() + 1.0,
    ];
    let origin = [lo[0] - before[0] * cell, lo[1] - before[1] * cell];
    let columns = ((all_hi[0] - origin[0]) / cell).floor() as usize + 2;
    let rows = ((all_hi[1] - origin[1]) / cell).floor() as usize + 2;
    StableGround::rasterise(origin, cell, columns, rows, |x, y| {
        let col = ((x - lo[0]) / cell).floor();
        let row = ((y - lo[1]) / cell).floor();
        !(col >= 0.0 && row >= 0.0 && changed.contains(&(col as usize, row as usize)))
    })
    .ok()
}

/// Running sums of one region's weighted mean.
#[derive(Debug, Clone, Copy, Default)]
struct Region {
    weighted: Vector3<f64>,
    weights: Vector3<f64>,
    count: usize,
}

impl Region {
    fn add(&mut self, difference: &Vector3<f64>, variance: &Vector3<f64>) {
        for k in 0..3 {
            if variance[k] > 0.0 && variance[k].is_finite() && difference[k].is_finite() {
                let w = 1.0 / variance[k];
                self.weighted[k] += w * difference[k];
                self.weights[k] += w;
            }
        }
        self.count += 1;
    }

    /// Largest |mean| / standard error over the three components.
    fn significance(&self, inflation: f64) -> f64 {
        (0..3)
            .filter(|&k| self.weights[k] > 0.0)
            .map(|k| {
                let mean = self.weighted[k] / self.weights[k];
                mean.abs() * self.weights[k].sqrt() / inflation
            })
            .fold(0.0, f64::max)
    }
}

/// Every inter-epoch tie point intersected in its base epoch (the reference when it observes the
/// point, else the epoch with the most observations) and in each other epoch with two or more
/// observations.
fn tie_differences(
    input: &SfmInput,
    rec: &Reconstruction,
    epoch_of: &[usize],
    reference: usize,
    noise_px: f64,
) -> Vec<TieDifference> {
    let mut out = Vec::new();
    for point in &rec.points {
        let mut by_epoch: BTreeMap<usize, Vec<PixelObservation<'_>>> = BTreeMap::new();
        for e in &point.observations {
            let image = e.image.index();
            let (Some(pose), Some(&epoch)) =
                (rec.poses.get(image).copied().flatten(), epoch_of.get(image))
            else {
                continue;
            };
            by_epoch.entry(epoch).or_default().push(PixelObservation {
                camera: rec.camera_of(input, image),
                pose,
                pixel: input.pixel(e),
                sigma_px: noise_px,
            });
        }
        by_epoch.retain(|_, obs| obs.len() >= 2);
        if by_epoch.len() < 2 {
            continue;
        }
        let base = if by_epoch.contains_key(&reference) {
            reference
        } else {
            by_epoch
                .iter()
                .max_by_key(|(e, obs)| (obs.len(), std::cmp::Reverse(**e)))
                .map(|(e, _)| *e)
                .unwrap_or(reference)
        };
        let Some(Ok(base_point)) = by_epoch.get(&base).map(|obs| intersect_weighted(obs)) else {
            continue;
        };
        for (&epoch, obs) in &by_epoch {
            if epoch == base {
                continue;
            }
            let Ok(other) = intersect_weighted(obs) else {
                continue;
            };
            let variance =
                Vector3::from_fn(|k, _| base_point.covariance[(k, k)] + other.covariance[(k, k)]);
            out.push(TieDifference {
                xy: [point.position.x, point.position.y],
                pair: (base, epoch),
                difference: other.position - base_point.position,
                variance,
            });
        }
    }
    out
}
