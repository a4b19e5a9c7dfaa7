//! Guided matching (Hartley & Zisserman 2004, §11.9; COLMAP's `guided_matching`): once a pair's
//! epipolar geometry is verified, each descriptor is compared only with the other image's
//! keypoints within the inlier threshold of its epipolar line. The ratio test then looks at far
//! fewer competitors, so correct matches that lost the global ratio test to a look-alike
//! elsewhere in the image (repeated windows, foliage, the same texture seen from further away)
//! come back; every match found this way is an inlier of the geometry by construction.
//!
//! The candidates near a line are found through a grid of cells over the second image, walked
//! along the line: a few hundred point–line tests and a few dozen descriptor distances per
//! keypoint instead of thousands.

use nalgebra::{Matrix3, Vector3};
use timesift_core::{Descriptors, Keypoint};

use crate::matcher::{FloatDistance, Nearest, describe, squared_hamming, to_words};
use crate::verify::VerifiedPair;
use crate::{Match, MatchOptions, MatchingError};
use timesift_geometry::homography::TwoViewType;

/// Side of the grid cells over the second image, pixels.
const CELL_PX: f64 = 32.0;

/// Options of [`guided_matches`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GuidedOptions {
    /// Largest distance of a keypoint of the second image from the epipolar line of its match,
    /// pixels (and of the first image's keypoint from the reverse line, with the mutual check),
    /// so the Sampson distance of every guided match is below it too.
    pub max_error_px: f64,
    /// Ratio test, mutual check and maximum distance, applied among the candidates of the band.
    pub matching: MatchOptions,
    /// [`grow_verified`]'s guided matches may be at most as far apart in descriptor space as
    /// this percentile of the pair's verified matches (at most 100).
    pub distance_percentile: usize,
}

impl Default for GuidedOptions {
    fn default() -> Self {
        Self {
            max_error_px: 4.0,
            matching: MatchOptions {
                ratio_on: FloatDistance::Angle,
                ..MatchOptions::default()
            },
            distance_percentile: 90,
        }
    }
}

/// Matches of keypoints `ka` (descriptors `da`) with `kb` (`db`) constrained by the fundamental
/// matrix `f` (pixels; `x_b' f x_a = 0`). Matches come ordered by query.
pub fn guided_matches(
    ka: &[Keypoint],
    da: &Descriptors,
    kb: &[Keypoint],
    db: &Descriptors,
    f: &Matrix3<f64>,
    options: &GuidedOptions,
) -> Result<Vec<Match>, MatchingError> {
    if !(options.max_error_px > 0.0 && options.max_error_px.is_finite()) {
        return Err(MatchingError::InvalidOption {
            name: "max_error_px",
            value: options.max_error_px,
            expected: "a positive number of pixels",
        });
    }
    check_ratio(&options.matching)?;
    let distance = DescriptorDistance::new(da, db)?;
    check_counts((ka, da), (kb, db))?;
    if !f.iter().all(|v| v.is_finite()) {
        return Ok(Vec::new());
    }
    let band = Region::Line {
        half_width: options.max_error_px,
    };
    Ok(matches_in_regions(
        (ka, kb),
        (f, &f.transpose()),
        band,
        &distance,
        &options.matching,
        matches!(da, Descriptors::Float { .. }),
    ))
}

/// Putative matches of keypoints `ka` (descriptors `da`) with `kb` (`db`) near the transfer of
/// homography `h` (`x_b ~ h x_a`, pixels): each keypoint is compared only with the other
/// image's keypoints within `radius_px` of where `h` takes it (and back through `h⁻¹` for the
/// mutual check), and the ratio test, mutual check and maximum distance of `matching` are
/// applied among those. For pairs a homography explains (nadir views of flat ground), where
/// epipolar lines are ill-determined: the radius admits the parallax of what stands off the
/// plane, so unlike [`guided_matches`] these are not inliers by construction and are to be
/// verified. Matches come ordered by query.
pub fn transfer_matches(
    (ka, da): (&[Keypoint], &Descriptors),
    (kb, db): (&[Keypoint], &Descriptors),
    h: &Matrix3<f64>,
    radius_px: f64,
    matching: &MatchOptions,
) -> Result<Vec<Match>, MatchingError> {
    if !(radius_px > 0.0 && radius_px.is_finite()) {
        return Err(MatchingError::InvalidOption {
            name: "radius_px",
            value: radius_px,
            expected: "a positive number of pixels",
        });
    }
    check_ratio(matching)?;
    let distance = DescriptorDistance::new(da, db)?;
    check_counts((ka, da), (kb, db))?;
    let Some(h_inv) = h.try_inverse().filter(|m| m.iter().all(|v| v.is_finite())) else {
        return Ok(Vec::new());
    };
    if !h.iter().all(|v| v.is_finite()) {
        return Ok(Vec::new());
    }
    let disc = Region::Disc { radius: radius_px };
    Ok(matches_in_regions(
        (ka, kb),
        (h, &h_inv),
        disc,
        &distance,
        matching,
        matches!(da, Descriptors::Float { .. }),
    ))
}

/// An error unless the ratio is in (0, 1].
fn check_ratio(matching: &MatchOptions) -> Result<(), MatchingError> {
    let ratio = matching.ratio;
    if !(ratio > 0.0 && ratio <= 1.0) {
        return Err(MatchingError::InvalidOption {
            name: "ratio",
            value: ratio as f64,
            expected: "in (0, 1]",
        });
    }
    Ok(())
}

/// An error unless every keypoint has one descriptor.
pub(crate) fn check_counts(
    (ka, da): (&[Keypoint], &Descriptors),
    (kb, db): (&[Keypoint], &Descriptors),
) -> Result<(), MatchingError> {
    for (keypoints, descriptors) in [(ka, da), (kb, db)] {
        if keypoints.len() != descriptors.len() {
            return Err(MatchingError::InvalidOption {
                name: "descriptors",
                value: descriptors.len() as f64,
                expected: "one descriptor per keypoint",
            });
        }
    }
    Ok(())
}

/// Where a keypoint's match is searched in the other image, given the pair's model applied to
/// the keypoint.
#[derive(Debug, Clone, Copy)]
enum Region {
    /// Within `half_width` pixels of the epipolar line `model · x`.
    Line { half_width: f64 },
    /// Within `radius` pixels of the transferred point `model · x`.
    Disc { radius: f64 },
}

/// The matches of `ka` with `kb` whose keypoints each lie in the other's region: `forward` takes
/// a keypoint of a to its region in b, `backward` one of b to its region in a (for the mutual
/// check); ratio test and maximum distance among the region's candidates.
fn matches_in_regions(
    (ka, kb): (&[Keypoint], &[Keypoint]),
    (forward, backward): (&Matrix3<f64>, &Matrix3<f64>),
    region: Region,
    distance: &DescriptorDistance<'_>,
    matching: &MatchOptions,
    float: bool,
) -> Vec<Match> {
    if ka.is_empty() || kb.is_empty() {
        return Vec::new();
    }
    let angles = matching.ratio_on == FloatDistance::Angle && float;
    let all_a: Vec<u32> = (0..ka.len() as u32).collect();
    let near_a = nearest_in_region(ka, &all_a, kb, forward, region, |i, j| distance.get(i, j));
    // The mutual check needs the reverse search only from the keypoints of b that some
    // keypoint of a chose.
    let near_b = if matching.mutual {
        let mut targets: Vec<u32> = near_a
            .iter()
            .filter(|n| n.passes(matching, angles))
            .map(|n| n.index)
            .collect();
        targets.sort_unstable();
        targets.dedup();
        let near = nearest_in_region(kb, &targets, ka, backward, region, |j, i| {
            distance.get(i, j)
        });
        let mut by_b = vec![Nearest::EMPTY; kb.len()];
        for (&j, n) in targets.iter().zip(near) {
            by_b[j as usize] = n;
        }
        Some(by_b)
    } else {
        None
    };
    let mut matches = Vec::new();
    for (i, near) in near_a.iter().enumerate() {
        if !near.passes(matching, angles) {
            continue;
        }
        let j = near.index as usize;
        if let Some(near_b) = &near_b {
            let back = &near_b[j];
            if back.index as usize != i || !back.passes(matching, angles) {
                continue;
            }
        }
        matches.push(Match {
            query: i as u32,
            train: j as u32,
            distance: near.best,
        });
    }
    matches
}

/// The inliers of a verified pair grown by guided matching with its fundamental matrix
/// (unchanged when a homography verified it or explains it as well: no reliable epipolar line
/// to search along).
pub fn grow_verified(
    ka: &[Keypoint],
    da: &Descriptors,
    kb: &[Keypoint],
    db: &Descriptors,
    verified: &VerifiedPair,
    options: &GuidedOptions,
) -> Result<Vec<Match>, MatchingError> {
    // Planar scenes and rotations determine F poorly (a rotation has no epipole): no lines.
    let f = match (&verified.fundamental, verified.kind) {
        (Some(f), TwoViewType::General) => f,
        _ => return Ok(verified.inliers.clone()),
    };
    // Few candidates lie in the band, so the ratio test alone is weak there (a keypoint whose
    // true match was not detected meets a lone candidate, and a lone candidate passes): guided
    // matches must also be as alike as the pair's verified matches are.
    let Some(matching) = as_alike_as(&verified.inliers, da, options) else {
        return Ok(verified.inliers.clone());
    };
    let options = GuidedOptions {
        matching,
        ..*options
    };
    let guided = guided_matches(ka, da, kb, db, f, &options)?;
    let grown = grow_inliers(&verified.inliers, &guided, ka.len(), kb.len());
    // One guided match can displace two inliers (one sharing each keypoint): never fewer.
    Ok(if grown.len() >= verified.inliers.len() {
        grown
    } else {
        verified.inliers.clone()
    })
}

/// `options.matching` with its maximum distance lowered to the `options.distance_percentile`
/// of the `verified` matches' distances (between descriptors like `descriptors`); `None`
/// without verified matches.
pub(crate) fn as_alike_as(
    verified: &[Match],
    descriptors: &Descriptors,
    options: &GuidedOptions,
) -> Option<MatchOptions> {
    let mut distances: Vec<f32> = verified.iter().map(|m| m.distance).collect();
    distances.sort_unstable_by(f32::total_cmp);
    let rank = (distances.len() * options.distance_percentile.min(100) / 100)
        .min(distances.len().saturating_sub(1));
    let typical = *distances.get(rank)?;
    // Match distances of float descriptors are chords; the options may compare angles.
    let typical = match (descriptors, options.matching.ratio_on) {
        (Descriptors::Float { .. }, FloatDistance::Angle) => 2.0 * (0.5 * typical).min(1.0).asin(),
        _ => typical,
    };
    Some(MatchOptions {
        max_distance: Some(
            options
                .matching
                .max_distance
                .map_or(typical, |m| m.min(typical)),
        ),
        ..options.matching
    })
}

/// The verified inliers of a pair grown by guided matching: the guided matches, plus every
/// original inlier whose keypoints no guided match uses (a match can lose the band's ratio test
/// only to a competitor that is itself on the line).
pub fn grow_inliers(inliers: &[Match], guided: &[Match], num_a: usize, num_b: usize) -> Vec<Match> {
    let mut used_a = vec![false; num_a];
    let mut used_b = vec![false; num_b];
    let mut out = Vec::with_capacity(guided.len() + inliers.len());
    for m in guided.iter().chain(inliers) {
        let (a, b) = (m.query as usize, m.train as usize);
        if a < num_a && b < num_b && !used_a[a] && !used_b[b] {
            used_a[a] = true;
            used_b[b] = true;
            out.push(*m);
        }
    }
    out.sort_by_key(|m| (m.query, m.train));
    out
}

/// For each keypoint `from[i]` with `i` in `which`, its two nearest descriptors among the
/// keypoints of `to` in its region (`model` applied to it: an epipolar line or a transferred
/// point). `squared_distance(i, j)` compares their descriptors; the distances come back
/// unsquared.
fn nearest_in_region(
    from: &[Keypoint],
    which: &[u32],
    to: &[Keypoint],
    model: &Matrix3<f64>,
    region: Region,
    squared_distance: impl Fn(usize, usize) -> f32,
) -> Vec<Nearest> {
    let grid = Grid::new(to);
    let mut cells = Vec::new();
    which
        .iter()
        .map(|&i| {
            let i = i as usize;
            let k = &from[i];
            let mut near = Nearest::EMPTY;
            let image = model * Vector3::new(k.x, k.y, 1.0);
            // The test of a candidate, once the cells it may lie in are listed.
            let inside = match region {
                Region::Line { half_width } => {
                    let norm = (image.x * image.x + image.y * image.y).sqrt();
                    if !(norm > 0.0 && norm.is_finite()) {
                        return near;
                    }
                    let line = image / norm;
                    grid.cells_near_line(&line, half_width, &mut cells);
                    Inside::Line { line, half_width }
                }
                Region::Disc { radius } => {
                    let (x, y) = (image.x / image.z, image.y / image.z);
                    if !(x.is_finite() && y.is_finite()) {
                        return near;
                    }
                    grid.cells_near_point(x, y, radius, &mut cells);
                    Inside::Disc {
                        x,
                        y,
                        squared_radius: radius * radius,
                    }
                }
            };
            for &cell in &cells {
                for &j in grid.members(cell) {
                    if inside.holds(&to[j as usize]) {
                        near.offer(squared_distance(i, j as usize), j);
                    }
                }
            }
            near.best = near.best.sqrt();
            near.second = near.second.sqrt();
            near
        })
        .collect()
}

/// One keypoint's region in the other image, in pixels.
enum Inside {
    Line {
        /// Normalised: (x, y) is a unit normal.
        line: Vector3<f64>,
        half_width: f64,
    },
    Disc {
        x: f64,
        y: f64,
        squared_radius: f64,
    },
}

impl Inside {
    #[inline]
    fn holds(&self, p: &Keypoint) -> bool {
        match *self {
            Inside::Line { line, half_width } => {
                (line.x * p.x + line.y * p.y + line.z).abs() <= half_width
            }
            Inside::Disc {
                x,
                y,
                squared_radius,
            } => (p.x - x).powi(2) + (p.y - y).powi(2) <= squared_radius,
        }
    }
}

/// Keypoints bucketed in square cells (compressed rows: the members of cell c are
/// `order[start[c]..start[c + 1]]`).
struct Grid {
    x0: f64,
    y0: f64,
    /// Side of a cell, pixels: [`CELL_PX`], or more for a huge extent (the grid has at most
    /// [`MAX_CELLS_PER_SIDE`] cells per side).
    cell: f64,
    cols: usize,
    rows: usize,
    start: Vec<usize>,
    /// Keypoints by cell; those with a non-finite coordinate are left out.
    order: Vec<u32>,
}

/// Most cells along a side of the grid: a stray keypoint far outside the frame (coordinates
/// come from files) cannot make the grid huge.
const MAX_CELLS_PER_SIDE: f64 = 4096.0;

impl Grid {
    fn new(keypoints: &[Keypoint]) -> Self {
        let finite = |k: &Keypoint| k.x.is_finite() && k.y.is_finite();
        let (mut x0, mut y0, mut x1, mut y1) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for (n, k) in keypoints.iter().filter(|k| finite(k)).enumerate() {
            if n == 0 {
                (x0, y0, x1, y1) = (k.x, k.y, k.x, k.y);
            }
            x0 = x0.min(k.x);
            y0 = y0.min(k.y);
            x1 = x1.max(k.x);
            y1 = y1.max(k.y);
        }
        let cell = CELL_PX.max((x1 - x0).max(y1 - y0) / MAX_CELLS_PER_SIDE);
        let cols = ((x1 - x0) / cell).floor() as usize + 1;
        let rows = ((y1 - y0) / cell).floor() as usize + 1;
        let index = |k: &Keypoint| {
            let c = (((k.x - x0) / cell) as usize).min(cols - 1);
            let r = (((k.y - y0) / cell) as usize).min(rows - 1);
            r * cols + c
        };
        let mut start = vec![0usize; cols * rows + 1];
        for k in keypoints.iter().filter(|k| finite(k)) {
            start[index(k) + 1] += 1;
        }
        for c in 0..cols * rows {
            start[c + 1] += start[c];
        }
        let mut next = start.clone();
        let mut order = vec![0u32; start[cols * rows]];
        for (i, k) in keypoints.iter().enumerate() {
            if finite(k) {
                let c = index(k);
                order[next[c]] = i as u32;
                next[c] += 1;
            }
        }
        Grid {
            x0,
            y0,
            cell,
            cols,
            rows,
            start,
            order,
        }
    }

    fn members(&self, cell: usize) -> &[u32] {
        &self.order[self.start[cell]..self.start[cell + 1]]
    }

    /// The cells that may hold points within `radius` of `(x, y)`, written into `out`.
    fn cells_near_point(&self, x: f64, y: f64, radius: f64, out: &mut Vec<usize>) {
        out.clear();
        let span = |lo: f64, origin: f64, count: usize| {
            let first = ((lo - radius - origin) / self.cell).floor();
            let last = ((lo + radius - origin) / self.cell).floor();
            if last < 0.0 || first >= count as f64 {
                return None;
            }
            Some((first.max(0.0) as usize, (last as usize).min(count - 1)))
        };
        let (Some((c0, c1)), Some((r0, r1))) =
            (span(x, self.x0, self.cols), span(y, self.y0, self.rows))
        else {
            return;
        };
        for r in r0..=r1 {
            out.extend((c0..=c1).map(|c| r * self.cols + c));
        }
    }

    /// The cells that may hold points within `band` of the line `l · (x, y, 1) = 0` (`l`
    /// normalised so that (l.x, l.y) is a unit normal), written into `out`.
    fn cells_near_line(&self, l: &Vector3<f64>, band: f64, out: &mut Vec<usize>) {
        out.clear();
        // Walk along the axis the line runs closer to: for each column (row) of cells, the
        // range of rows (columns) the band crosses in it.
        let horizontal = l.y.abs() >= l.x.abs();
        let (steps, span) = if horizontal {
            (self.cols, self.rows)
        } else {
            (self.rows, self.cols)
        };
        for s in 0..steps {
            // Along-axis extent of this strip of cells, in pixels.
            let (lo, hi, origin_across) = if horizontal {
                let lo = self.x0 + s as f64 * self.cell;
                (lo, lo + self.cell, self.y0)
            } else {
                let lo = self.y0 + s as f64 * self.cell;
                (lo, lo + self.cell, self.x0)
            };
            // Across-axis coordinate of the line at `t` along: a·t + b·u + c = 0 with (a, b)
            // the along and across components of the normal.
            let (a, b) = if horizontal { (l.x, l.y) } else { (l.y, l.x) };
            let across = |t: f64| -(a * t + l.z) / b;
            let half_width = band / b.abs();
            let (u0, u1) = (across(lo), across(hi));
            let (u_min, u_max) = (u0.min(u1) - half_width, u0.max(u1) + half_width);
            let first = ((u_min - origin_across) / self.cell).floor();
            let last = ((u_max - origin_across) / self.cell).floor();
            if last < 0.0 || first >= span as f64 {
                continue;
            }
            let first = first.max(0.0) as usize;
            let last = (last as usize).min(span - 1);
            for u in first..=last {
                out.push(if horizontal {
                    u * self.cols + s
                } else {
                    s * self.cols + u
                });
            }
        }
    }
}

/// Squared distances between descriptors of the two images (Euclidean, or Hamming bits), as
/// [`Nearest`] expects them once their square roots are taken.
enum DescriptorDistance<'a> {
    Float {
        dim: usize,
        a: &'a [f32],
        b: &'a [f32],
    },
    /// As 64-bit words, like the exhaustive matcher's.
    Binary {
        words: usize,
        a: Vec<u64>,
        b: Vec<u64>,
    },
}

impl<'a> DescriptorDistance<'a> {
    fn new(a: &'a Descriptors, b: &'a Descriptors) -> Result<Self, MatchingError> {
        match (a, b) {
            (
                Descriptors::Float { dim: da, data: xa },
                Descriptors::Float { dim: db, data: xb },
            ) if da == db => Ok(DescriptorDistance::Float {
                dim: *da,
                a: xa,
                b: xb,
            }),
            (
                Descriptors::Binary {
                    bytes: ba,
                    data: xa,
                },
                Descriptors::Binary {
                    bytes: bb,
                    data: xb,
                },
            ) if ba == bb => Ok(DescriptorDistance::Binary {
                words: ba.div_ceil(8),
                a: to_words(xa, *ba),
                b: to_words(xb, *bb),
            }),
            _ => Err(MatchingError::IncompatibleDescriptors {
                a: describe(a),
                b: describe(b),
            }),
        }
    }

    fn get(&self, i: usize, j: usize) -> f32 {
        match self {
            DescriptorDistance::Float { dim, a, b } => {
                squared_euclidean(&a[i * dim..(i + 1) * dim], &b[j * dim..(j + 1) * dim])
            }
            DescriptorDistance::Binary { words, a, b } => squared_hamming(
                &a[i * words..(i + 1) * words],
                &b[j * words..(j + 1) * words],
            ),
        }
    }
}

/// ‖x − y‖², in eight independent lanes so that it vectorises.
#[inline]
fn squared_euclidean(x: &[f32], y: &[f32]) -> f32 {
    const LANES: usize = 8;
    let mut lanes = [0.0f32; LANES];
    let (xc, yc) = (x.chunks_exact(LANES), y.chunks_exact(LANES));
    let tail: f32 = xc
        .remainder()
        .iter()
        .zip(yc.remainder())
        .map(|(p, q)| (p - q) * (p - q))
        .sum();
    for (p, q) in xc.zip(yc) {
        for k in 0..LANES {
            let d = p[k] - q[k];
            lanes[k] += d * d;
        }
    }
    lanes.iter().sum::<f32>() + tail
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use timesift_core::SeededRng;

    fn keypoint(x: f64, y: f64) -> Keypoint {
        Keypoint {
            x,
            y,
            scale: 2.0,
            orientation: 0.0,
            response: 1.0,
            octave: 0,
        }
    }

    fn unit_descriptor(rng: &mut SeededRng, dim: usize) -> Vec<f32> {
        let v: Vec<f32> = (0..dim).map(|_| rng.normal() as f32).collect();
        let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
        v.into_iter().map(|x| x / norm).collect()
    }

    /// A copy of `d` moved a little (angle about `noise` radians).
    fn perturbed(rng: &mut SeededRng, d: &[f32], noise: f64) -> Vec<f32> {
        let v: Vec<f32> = d
            .iter()
            .map(|x| x + (noise / (d.len() as f64).sqrt() * rng.normal()) as f32)
            .collect();
        let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
        v.into_iter().map(|x| x / norm).collect()
    }

    /// The fundamental matrix of a rectified stereo pair: epipolar lines are image rows.
    fn rectified() -> Matrix3<f64> {
        Matrix3::new(0.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0)
    }

    /// Every keypoint of image a has its true match on the same row of image b, 40–200 px to
    /// the left, and a look-alike about as close to it in descriptor space `offset` px off the
    /// row (rows are 9 px apart).
    fn stereo_with_lookalikes(
        n: usize,
        offset: f64,
    ) -> (Vec<Keypoint>, Descriptors, Vec<Keypoint>, Descriptors) {
        let mut rng = SeededRng::new(7);
        let (mut ka, mut kb, mut da, mut db) = (vec![], vec![], vec![], vec![]);
        for i in 0..n {
            let (x, y) = (300.0 + rng.uniform() * 600.0, 20.0 + 9.0 * i as f64);
            let d = unit_descriptor(&mut rng, 128);
            ka.push(keypoint(x, y));
            da.extend_from_slice(&d);
            kb.push(keypoint(x - rng.uniform_range(40.0, 200.0), y));
            db.extend(perturbed(&mut rng, &d, 0.3));
            kb.push(keypoint(x - rng.uniform_range(-300.0, 300.0), y + offset));
            db.extend(perturbed(&mut rng, &d, 0.28));
        }
        let float = |data| Descriptors::Float { dim: 128, data };
        (ka, float(da), kb, float(db))
    }

    #[test]
    fn guided_matching_recovers_matches_that_lose_the_global_ratio_test() {
        let n = 60;
        let (ka, da, kb, db) = stereo_with_lookalikes(n, 30.0);
        let options = GuidedOptions::default();
        // Globally, each true match has a look-alike as its rival: the ratio test drops it.
        let global = crate::match_descriptors(&da, &db, &options.matching).unwrap();
        assert!(global.len() < n / 10, "{} global matches", global.len());
        let guided = guided_matches(&ka, &da, &kb, &db, &rectified(), &options).unwrap();
        assert_eq!(guided.len(), n);
        for m in &guided {
            // True matches are the even keypoints of b.
            assert_eq!(m.train, 2 * m.query, "{m:?}");
        }
    }

    #[test]
    fn a_lookalike_on_the_line_still_fails_the_ratio_test() {
        let (ka, da, kb, db) = stereo_with_lookalikes(40, 0.5);
        let guided =
            guided_matches(&ka, &da, &kb, &db, &rectified(), &GuidedOptions::default()).unwrap();
        assert!(guided.len() < 4, "{} matches", guided.len());
    }

    #[test]
    fn grown_matches_are_as_alike_as_the_verified_ones() {
        let n = 60;
        let (ka, da, kb, db) = stereo_with_lookalikes(n, 30.0);
        // The true matches differ by about 0.3 rad: verified matches ten times closer set a
        // bound that none of them meets; verified matches as far apart admit them all.
        let verified = |distance: f32| VerifiedPair {
            model: crate::verify::EpipolarModel::Fundamental,
            kind: timesift_geometry::homography::TwoViewType::General,
            inliers: (0..10)
                .map(|i| Match {
                    query: i,
                    train: 2 * i,
                    distance,
                })
                .collect(),
            homography_inliers: 0,
            fundamental: Some(rectified()),
            homography: None,
        };
        let options = GuidedOptions::default();
        let tight = grow_verified(&ka, &da, &kb, &db, &verified(0.03), &options).unwrap();
        assert_eq!(tight.len(), 10);
        let loose = grow_verified(&ka, &da, &kb, &db, &verified(0.6), &options).unwrap();
        assert_eq!(loose.len(), n);
        assert!(loose.iter().all(|m| m.train == 2 * m.query));
        // A homography gives no lines to search along: the inliers stay as they are.
        let planar = VerifiedPair {
            fundamental: None,
            ..verified(0.6)
        };
        assert_eq!(
            grow_verified(&ka, &da, &kb, &db, &planar, &options)
                .unwrap()
                .len(),
            10
        );
    }

    #[test]
    fn bad_inputs_are_errors() {
        let (ka, da, kb, _) = stereo_with_lookalikes(3, 30.0);
        let binary = Descriptors::Binary {
            bytes: 32,
            data: vec![0; 32 * kb.len()],
        };
        let f = rectified();
        assert!(matches!(
            guided_matches(&ka, &da, &kb, &binary, &f, &GuidedOptions::default()),
            Err(MatchingError::IncompatibleDescriptors { .. })
        ));
        let options = GuidedOptions {
            max_error_px: 0.0,
            ..GuidedOptions::default()
        };
        assert!(matches!(
            guided_matches(&ka, &da, &kb, &da, &f, &options),
            Err(MatchingError::InvalidOption {
                name: "max_error_px",
                ..
            })
        ));
        // Fewer descriptors than keypoints.
        assert!(matches!(
            guided_matches(&ka, &da, &kb, &da, &f, &GuidedOptions::default()),
            Err(MatchingError::InvalidOption {
                name: "descriptors",
                ..
            })
        ));
    }

    /// Keypoints of image a and their true matches in image b at `h`'s transfer plus up to
    /// `parallax` px (what stands off the plane), each with a look-alike about as close in
    /// descriptor space 60 px or more from the transfer. True matches are the even keypoints of
    /// b.
    fn planar_with_lookalikes(
        n: usize,
        h: &Matrix3<f64>,
        parallax: f64,
    ) -> (Vec<Keypoint>, Descriptors, Vec<Keypoint>, Descriptors) {
        let mut rng = SeededRng::new(11);
        let (mut ka, mut kb, mut da, mut db) = (vec![], vec![], vec![], vec![]);
        for _ in 0..n {
            let (x, y) = (
                rng.uniform_range(50.0, 950.0),
                rng.uniform_range(50.0, 700.0),
            );
            let d = unit_descriptor(&mut rng, 128);
            ka.push(keypoint(x, y));
            da.extend_from_slice(&d);
            let t = h * Vector3::new(x, y, 1.0);
            let angle = rng.uniform_range(0.0, std::f64::consts::TAU);
            let off = parallax * rng.uniform();
            kb.push(keypoint(
                t.x / t.z + off * angle.cos(),
                t.y / t.z + off * angle.sin(),
            ));
            db.extend(perturbed(&mut rng, &d, 0.3));
            let far = rng.uniform_range(60.0, 400.0);
            kb.push(keypoint(
                t.x / t.z + far * angle.sin(),
                t.y / t.z - far * angle.cos(),
            ));
            db.extend(perturbed(&mut rng, &d, 0.28));
        }
        let float = |data| Descriptors::Float { dim: 128, data };
        (ka, float(da), kb, float(db))
    }

    /// A homography of a nadir pair over flat ground: a shift, a small rotation and scale, a
    /// little perspective.
    fn ground_homography() -> Matrix3<f64> {
        let (c, s) = (0.05f64.cos() * 1.02, 0.05f64.sin() * 1.02);
        Matrix3::new(c, -s, -180.0, s, c, 35.0, 1e-5, -2e-5, 1.0)
    }

    #[test]
    fn transfer_matching_finds_matches_off_the_plane_within_its_radius() {
        let n = 80;
        let h = ground_homography();
        let (ka, da, kb, db) = planar_with_lookalikes(n, &h, 10.0);
        let matching = GuidedOptions::default().matching;
        let global = crate::match_descriptors(&da, &db, &matching).unwrap();
        assert!(global.len() < n / 10, "{} global matches", global.len());
        let near = transfer_matches((&ka, &da), (&kb, &db), &h, 16.0, &matching).unwrap();
        assert_eq!(near.len(), n);
        assert!(near.iter().all(|m| m.train == 2 * m.query), "{near:?}");
        // A radius smaller than the parallax misses the true matches that stand further off,
        // and a look-alike never comes in their place.
        let tight = transfer_matches((&ka, &da), (&kb, &db), &h, 5.0, &matching).unwrap();
        assert!(tight.len() < n && tight.len() > n / 5, "{}", tight.len());
        assert!(tight.iter().all(|m| m.train == 2 * m.query));
    }

    #[test]
    fn transfer_matching_rejects_bad_radii_and_singular_homographies() {
        let h = ground_homography();
        let (ka, da, kb, db) = planar_with_lookalikes(10, &h, 0.0);
        let matching = GuidedOptions::default().matching;
        for radius in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(matches!(
                transfer_matches((&ka, &da), (&kb, &db), &h, radius, &matching),
                Err(MatchingError::InvalidOption {
                    name: "radius_px",
                    ..
                })
            ));
        }
        let singular = Matrix3::new(1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
        let none = transfer_matches((&ka, &da), (&kb, &db), &singular, 8.0, &matching).unwrap();
        assert!(none.is_empty());
        let nan = Matrix3::from_element(f64::NAN);
        assert!(
            transfer_matches((&ka, &da), (&kb, &db), &nan, 8.0, &matching)
                .unwrap()
                .is_empty()
        );
        assert!(matches!(
            transfer_matches((&ka, &da), (&kb[1..], &db), &h, 8.0, &matching),
            Err(MatchingError::InvalidOption {
                name: "descriptors",
                ..
            })
        ));
    }

    #[test]
    fn grown_inliers_never_use_a_keypoint_twice() {
        let m = |query, train| Match {
            query,
            train,
            distance: 0.1,
        };
        let inliers = [m(0, 0), m(1, 1), m(2, 2)];
        let guided = [m(0, 0), m(1, 5), m(3, 2), m(4, 4)];
        let grown = grow_inliers(&inliers, &guided, 5, 6);
        // Guided matches first; the original 1→1 and 2→2 collide with guided 1→5 and 3→2.
        let pairs: Vec<_> = grown.iter().map(|m| (m.query, m.train)).collect();
        assert_eq!(pairs, vec![(0, 0), (1, 5), (3, 2), (4, 4)]);
    }

    #[test]
    fn stray_keypoints_cannot_blow_up_the_grid() {
        let mut points = vec![keypoint(10.0, 10.0), keypoint(1e12, -1e12)];
        points.push(keypoint(f64::NAN, 5.0));
        points.push(keypoint(f64::INFINITY, 5.0));
        let grid = Grid::new(&points);
        assert!(grid.cols <= 4097 && grid.rows <= 4097);
        // The two finite keypoints are bucketed, the others left out.
        assert_eq!(grid.order.len(), 2);
        let only_strays = Grid::new(&points[2..]);
        assert!(only_strays.order.is_empty());
        let mut cells = Vec::new();
        only_strays.cells_near_line(&Vector3::new(0.0, 1.0, -5.0), 4.0, &mut cells);
        assert!(cells.iter().all(|&c| only_strays.members(c).is_empty()));
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// The grid walk finds exactly the points within the band that a scan of all points finds.
        #[test]
        fn grid_walk_finds_every_point_near_a_line(
            seed in 0u64..1000,
            angle in 0.0f64..std::f64::consts::PI,
            offset in -300.0f64..1300.0,
            band in 0.5f64..40.0,
        ) {
            let mut rng = SeededRng::new(seed);
            let points: Vec<Keypoint> = (0..400)
                .map(|_| keypoint(rng.uniform_range(-5.0, 1030.0), rng.uniform_range(0.0, 770.0)))
                .collect();
            let line = Vector3::new(angle.cos(), angle.sin(), -offset);
            let grid = Grid::new(&points);
            let mut cells = Vec::new();
            grid.cells_near_line(&line, band, &mut cells);
            let mut found: Vec<u32> = cells
                .iter()
                .flat_map(|&c| grid.members(c).iter().copied())
                .filter(|&j| {
                    let p = &points[j as usize];
                    (line.x * p.x + line.y * p.y + line.z).abs() <= band
                })
                .collect();
            found.sort_unstable();
            let expected: Vec<u32> = (0..points.len() as u32)
                .filter(|&j| {
                    let p = &points[j as usize];
                    (line.x * p.x + line.y * p.y + line.z).abs() <= band
                })
                .collect();
            prop_assert_eq!(found, expected);
        }
    }
}
