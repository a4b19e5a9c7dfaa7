//! The coarse level of the conjugate gradients' preconditioner: small similarity motions of the
//! cameras of each tile of ground, solved exactly, added to the block-Jacobi level.
//!
//! Why: block Jacobi inverts each camera's own 6 × 6 block, so what converges slowly is what
//! moves many cameras together: the whole block or a part of it shifted, turned or scaled, which
//! its tie points barely resist (only the priors, or the ties to the rest of the block, do), and
//! an intrinsic moved together with what compensates it in every camera of its group. On the
//! scale bench's 800-image, 8-epoch block the smallest eigenvalues of the block-Jacobi
//! preconditioned system were such motions; conjugate gradients to a relative residual of 10⁻⁶
//! took 294 products per step with block Jacobi alone in the first adjustment of the seeded
//! block and 51 with this coarse level; 225 and 102 in an adjustment freeing seven intrinsics per
//! epoch. Tiles are taken across epochs: what ties the epochs is the ground they share. A
//! two-level additive Schwarz preconditioner (Toselli & Widlund, *Domain Decomposition Methods*;
//! the coarse columns play the part of the rigid-body modes of smoothed aggregation).
//!
//! Coarse columns, per tile τ with pivot p (the mean of its cameras' centres), in the pose
//! update of [`timesift_core::Pose::retract`] (`R ← exp([δω]×) R`, `t ← t + δt`):
//! - a world translation `d`: `δt = −R d`;
//! - a world rotation `θ` about p: `δω = −R θ`, `δt = R (θ × p)`;
//! - a scale `s` about p: `δt = s (t + R p)`.
//!
//! Every reduced-side column that is not a pose's (intrinsics, GNSS offsets, points on scale
//! bars) is a coarse column of its own, extended to the poses it couples to by each camera's
//! response (`−S_ii⁻¹ S_ic`, found anew for each damped system): the shift of every camera
//! against its flight's offset, a focal length against every camera's height, are then in the
//! coarse space.

use nalgebra::{DMatrix, DVector, Matrix3, Matrix6, Vector3, Vector6};
use rayon::prelude::*;

use crate::layout::Layout;
use crate::problem::BundleProblem;
use crate::reduced::Reduced;

/// Cameras per tile, about: the coarse space has seven columns per tile.
const CAMERAS_PER_TILE: usize = 16;

/// Most reduced-side columns outside the poses that the coarse space takes one by one; beyond
/// it (e.g. thousands of scale-bar points) the coarse level is left out.
const MAX_OTHER_COLUMNS: usize = 2000;

/// Coarse columns per tile: translation (3), rotation (3), scale (1).
const PER_TILE: usize = 7;

/// Sparse rows: per row, the range of its entries in `cols`/`vals`.
#[derive(Default)]
struct Rows {
    ptr: Vec<usize>,
    cols: Vec<usize>,
    vals: Vec<f64>,
}

impl Rows {
    fn row(&self, r: usize) -> impl Iterator<Item = (usize, f64)> + '_ {
        let span = self.ptr[r]..self.ptr[r + 1];
        self.cols[span.clone()]
            .iter()
            .copied()
            .zip(self.vals[span].iter().copied())
    }

    fn push_row(&mut self, entries: impl IntoIterator<Item = (usize, f64)>) {
        if self.ptr.is_empty() {
            self.ptr.push(0);
        }
        for (c, v) in entries {
            self.cols.push(c);
            self.vals.push(v);
        }
        self.ptr.push(self.cols.len());
    }
}

/// The coarse space of one adjustment: the tiles' motions of the free poses (fixed for the
/// adjustment) and the reduced-side columns outside the poses, whose cameras' response is
/// found anew for each damped system ([`CoarseSpace::correction`]).
pub(crate) struct CoarseSpace {
    /// Per reduced-side row, its tile-motion entries (poses' rows only).
    tiles: Rows,
    /// Reduced-side offset of each free pose.
    poses: Vec<usize>,
    /// Coarse column of each reduced-side column outside the poses.
    other: Vec<Option<usize>>,
    /// The first reduced-side column outside the poses (they follow the poses in the layout).
    first_other: usize,
    /// Coarse columns.
    k: usize,
}

impl CoarseSpace {
    /// The coarse space of the free poses' tiles and the other reduced-side columns; `None` when
    /// the reduced side holds no pose (poses eliminated) or too many other columns.
    pub(crate) fn new(p: &BundleProblem, layout: &Layout) -> Option<Self> {
        let n = layout.num_camera_params;
        let free: Vec<(usize, usize)> = layout
            .pose_offset
            .iter()
            .enumerate()
            .filter_map(|(i, off)| off.map(|o| (i, o)))
            .collect();
        if free.is_empty() {
            return None;
        }
        let centres: Vec<Vector3<f64>> = free
            .iter()
            .map(|&(i, _)| p.images[i].pose.center())
            .collect();
        let tile_of = tiles(&centres, free.len().div_ceil(CAMERAS_PER_TILE));
        let tiles = tile_of.iter().max().map_or(0, |t| t + 1);
        let mut pivots = vec![(Vector3::zeros(), 0usize); tiles];
        for (c, &t) in centres.iter().zip(&tile_of) {
            pivots[t].0 += c;
            pivots[t].1 += 1;
        }
        let pivots: Vec<Vector3<f64>> = pivots
            .into_iter()
            .map(|(sum, count)| sum / count.max(1) as f64)
            .collect();
        let mut rows: Vec<Vec<(usize, f64)>> = vec![Vec::new(); n];
        let mut is_pose = vec![false; n];
        for (&(i, off), &t) in free.iter().zip(&tile_of) {
            let pose = &p.images[i].pose;
            let r: Matrix3<f64> = *pose.rotation.to_rotation_matrix().matrix();
            let base = PER_TILE * t;
            let pivot = pivots[t];
            let lever = pose.translation + r * pivot;
            for e in 0..3 {
                let axis = Vector3::ith(e, 1.0);
                let turned = r * axis;
                let moved = r * axis.cross(&pivot);
                for a in 0..3 {
                    rows[off + a].push((base + 3 + e, -turned[a]));
                    rows[off + 3 + a].push((base + e, -turned[a]));
                    rows[off + 3 + a].push((base + 3 + e, moved[a]));
                }
            }
            for a in 0..3 {
                rows[off + 3 + a].push((base + 6, lever[a]));
            }
            is_pose[off..off + 6].fill(true);
        }
        if is_pose.iter().filter(|&&x| !x).count() > MAX_OTHER_COLUMNS {
            return None;
        }
        let mut k = PER_TILE * tiles;
        let other: Vec<Option<usize>> = is_pose
            .iter()
            .map(|&pose| {
                (!pose).then(|| {
                    k += 1;
                    k - 1
                })
            })
            .collect();
        let first_other = is_pose.iter().position(|&x| !x).unwrap_or(n);
        let mut tile_rows = Rows::default();
        for row in rows {
            tile_rows.push_row(row);
        }
        Some(CoarseSpace {
            tiles: tile_rows,
            poses: free.iter().map(|&(_, off)| off).collect(),
            other,
            first_other,
            k,
        })
    }

    /// The prolongation `P` for the damped system `s`: the tiles' motions, and each other
    /// column with the response of every camera it couples to (`−S_ii⁻¹ S_ic` on camera `i`'s
    /// pose rows: what the camera would do, alone, if that intrinsic or offset moved), so that
    /// an intrinsic's coarse column moves it together with what compensates it in each camera.
    /// Without that response a focal length or principal point changes at the cost of every
    /// camera's tie points; with it, at the cost of what the cameras cannot compensate (scale
    /// bench, 800 images, self-calibration of seven intrinsics per epoch: 343 products to 10⁻⁶
    /// with block Jacobi, 207 with tiles and bare intrinsic columns, 76 with the responses).
    fn prolongation(&self, s: &Reduced) -> Rows {
        let n = self.other.len();
        let mut response: Vec<Vec<(usize, f64)>> = vec![Vec::new(); n];
        for &off in &self.poses {
            let block = Matrix6::from_fn(|a, b| s.get(off + a, off + b));
            let Some(inverse) = block.cholesky().map(|c| c.inverse()) else {
                continue;
            };
            // The other columns coupled to this pose: the tails of its columns' stored rows.
            let mut coupling: Vec<(usize, Vector6<f64>)> = Vec::new();
            for a in 0..6 {
                for (c, v) in s.column_tail(off + a, self.first_other) {
                    let slot = match coupling.binary_search_by_key(&c, |x| x.0) {
                        Ok(slot) => slot,
                        Err(slot) => {
                            coupling.insert(slot, (c, Vector6::zeros()));
                            slot
                        }
                    };
                    coupling[slot].1[a] = v;
                }
            }
            for (c, column) in coupling {
                let Some(coarse) = self.other[c] else {
                    continue;
                };
                let moved = -(inverse * column);
                for a in 0..6 {
                    response[off + a].push((coarse, moved[a]));
                }
            }
        }
        let mut rows = Rows::default();
        for (r, response) in response.into_iter().enumerate() {
            let own = self.other[r].map(|c| (c, 1.0));
            rows.push_row(self.tiles.row(r).chain(response).chain(own));
        }
        rows
    }

    /// The coarse correction for the damped system `s`: `P (Pᵀ S P)⁻¹ Pᵀ`, factorised once per
    /// step; `None` when the coarse system is not positive definite (then block Jacobi alone).
    pub(crate) fn correction(&self, s: &Reduced) -> Option<CoarseCorrection> {
        let p = self.prolongation(s);
        let k = self.k;
        let a = coarse_matrix(s, &p, k);
        // Columns of very different magnitudes (metres of lever, unit shifts): scaled to a unit
        // diagonal before the factorisation, with a relative ridge for tiles whose motions are
        // not independent (a tile of one camera has seven motions of its six parameters; the
        // dependent combination is in P's null space, where the ridge does nothing).
        let scale: Vec<f64> = (0..k)
            .map(|i| {
                let d = a[(i, i)];
                if d > 0.0 { 1.0 / d.sqrt() } else { 0.0 }
            })
            .collect();
        let scaled = DMatrix::from_fn(k, k, |i, j| {
            0.5 * (a[(i, j)] + a[(j, i)]) * scale[i] * scale[j]
                + if i == j { COARSE_RIDGE } else { 0.0 }
        });
        let factor = scaled.cholesky()?;
        Some(CoarseCorrection {
            p,
            k,
            scale: DVector::from_vec(scale),
            factor,
        })
    }
}

/// `Pᵀ S P` (k × k) for the `n × k` prolongation `p` (`n` rows of `s`).
/// `W = S P` (dense, n × k, row-major) is computed by bands of rows, each summing its rows'
/// terms in the order of a serial pass over S's lower triangle, column by column (the same bits
/// on any number of threads); then `A = Pᵀ W` row by row of A, from P's columns. Serial, it was
/// a fifteenth of the align stage's time on 1,600 images.
fn coarse_matrix(s: &Reduced, p: &Rows, k: usize) -> DMatrix<f64> {
    let n = p.ptr.len().saturating_sub(1);
    let band = n.div_ceil(PRODUCT_BANDS).max(1);
    let mut w = vec![0.0; n * k];
    w.par_chunks_mut((band * k).max(1))
        .enumerate()
        .for_each(|(b, wb)| {
            let rows = b * band..((b + 1) * band).min(n);
            s.for_each_lower_touching(rows.clone(), |r, c, v| {
                if v == 0.0 {
                    return;
                }
                if rows.contains(&r) {
                    for (j, pj) in p.row(c) {
                        wb[(r - rows.start) * k + j] += v * pj;
                    }
                }
                if r != c && rows.contains(&c) {
                    for (j, pj) in p.row(r) {
                        wb[(c - rows.start) * k + j] += v * pj;
                    }
                }
            });
        });
    let mut columns_of_p: Vec<Vec<(usize, f64)>> = vec![Vec::new(); k];
    for r in 0..n {
        for (i, pi) in p.row(r) {
            columns_of_p[i].push((r, pi));
        }
    }
    let mut rows_of_a = vec![0.0; k * k];
    rows_of_a
        .par_chunks_mut(k.max(1))
        .zip(columns_of_p.par_iter())
        .for_each(|(a, column)| {
            for &(r, pi) in column {
                for (a, &wj) in a.iter_mut().zip(&w[r * k..(r + 1) * k]) {
                    *a += pi * wj;
                }
            }
        });
    DMatrix::from_row_slice(k, k, &rows_of_a)
}

/// Bands of rows of `S P` computed as one task each (fixed, so that nothing depends on the
/// threads; enough for a machine's cores, few enough that each band's pass over the columns
/// before it stays small beside its entries).
const PRODUCT_BANDS: usize = 16;

/// Ridge added to the unit diagonal of the scaled coarse system.
const COARSE_RIDGE: f64 = 1e-10;

/// `P (Pᵀ S P)⁻¹ Pᵀ` for one damped system.
pub(crate) struct CoarseCorrection {
    p: Rows,
    k: usize,
    scale: DVector<f64>,
    factor: nalgebra::Cholesky<f64, nalgebra::Dyn>,
}

impl CoarseCorrection {
    /// `z += P (Pᵀ S P)⁻¹ Pᵀ r`.
    pub(crate) fn add_to(&self, r: &DVector<f64>, z: &mut DVector<f64>) {
        let mut coarse = DVector::zeros(self.k);
        for i in 0..r.len() {
            for (c, v) in self.p.row(i) {
                coarse[c] += v * r[i];
            }
        }
        let solved = self
            .factor
            .solve(&coarse.component_mul(&self.scale))
            .component_mul(&self.scale);
        for i in 0..z.len() {
            z[i] += self.p.row(i).map(|(c, v)| v * solved[c]).sum::<f64>();
        }
    }
}

/// A tile index per centre: square tiles on the two directions of largest spread of the centres
/// (the ground plane of an aerial block, whatever the world frame), about `count` of them over
/// the centres' extent; numbered densely from 0.
fn tiles(centres: &[Vector3<f64>], count: usize) -> Vec<usize> {
    let n = centres.len().max(1) as f64;
    let mean = centres.iter().sum::<Vector3<f64>>() / n;
    let covariance = centres
        .iter()
        .map(|c| (c - mean) * (c - mean).transpose())
        .sum::<Matrix3<f64>>()
        / n;
    let eigen = covariance.symmetric_eigen();
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eigen.eigenvalues[b].total_cmp(&eigen.eigenvalues[a]));
    let (u, v) = (
        eigen.eigenvectors.column(order[0]).into_owned(),
        eigen.eigenvectors.column(order[1]).into_owned(),
    );
    let projected: Vec<(f64, f64)> = centres
        .iter()
        .map(|c| ((c - mean).dot(&u), (c - mean).dot(&v)))
        .collect();
    let (mut lo, mut hi) = (
        (f64::INFINITY, f64::INFINITY),
        (f64::NEG_INFINITY, f64::NEG_INFINITY),
    );
    for &(a, b) in &projected {
        lo = (lo.0.min(a), lo.1.min(b));
        hi = (hi.0.max(a), hi.1.max(b));
    }
    let (w, h) = ((hi.0 - lo.0).max(0.0), (hi.1 - lo.1).max(0.0));
    // Square tiles of side `side`, `count` of them over w × h (a strip: along its length).
    let area = (w * h).max(w.max(h) * w.max(h) / count.max(1) as f64);
    let side = (area / count.max(1) as f64).sqrt();
    if !(side > 0.0) || !side.is_finite() {
        return vec![0; centres.len()];
    }
    let columns = (w / side).floor() as usize + 1;
    let raw: Vec<usize> = projected
        .iter()
        .map(|&(a, b)| {
            let i = ((a - lo.0) / side).floor() as usize;
            let j = ((b - lo.1) / side).floor() as usize;
            j * columns + i
        })
        .collect();
    let mut ids: Vec<usize> = raw.clone();
    ids.sort_unstable();
    ids.dedup();
    raw.iter()
        .map(|t| ids.binary_search(t).unwrap_or(0))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::reduced::SparsePattern;
    use timesift_core::SeededRng;

    /// `Pᵀ S P` by bands of rows is the serial pass's, bit for bit, on any number of threads and
    /// in either storage of `S`.
    #[test]
    fn the_coarse_matrix_is_the_serial_products_on_any_number_of_threads() {
        let mut rng = SeededRng::new(5);
        let (n, k) = (75, 11);
        // Blocks of 3 columns coupled in random groups.
        let groups: Vec<Vec<usize>> = (0..30)
            .map(|_| {
                let mut cols: Vec<usize> = (0..3)
                    .flat_map(|_| {
                        let b = (rng.uniform() * 25.0) as usize % 25;
                        3 * b..3 * b + 3
                    })
                    .collect();
                cols.sort_unstable();
                cols.dedup();
                cols
            })
            .collect();
        let pattern = SparsePattern::new(n, &groups, false).unwrap();
        let mut sparse = Reduced::sparse(pattern);
        let mut dense = Reduced::dense(n);
        for cols in &groups {
            for &r in cols {
                for &c in cols.iter().filter(|&&c| c <= r) {
                    let v = rng.normal();
                    sparse.add(r, c, v);
                    dense.add(r, c, v);
                    if r != c {
                        dense.add(c, r, v);
                    }
                }
            }
        }
        let mut p = Rows::default();
        for _ in 0..n {
            let entries: Vec<(usize, f64)> = (0..3)
                .map(|q| {
                    (
                        ((rng.uniform() * 3.0) as usize).min(2) + 4 * q % k,
                        rng.normal(),
                    )
                })
                .collect();
            let mut entries = entries;
            entries.sort_by_key(|e| e.0);
            entries.dedup_by_key(|e| e.0);
            p.push_row(entries);
        }
        // The serial pass over the whole lower triangle, then Pᵀ W by rows of P.
        let serial = |s: &Reduced| {
            let mut w = vec![0.0; n * k];
            s.for_each_lower_touching(0..n, |r, c, v| {
                if v == 0.0 {
                    return;
                }
                for (j, pj) in p.row(c) {
                    w[r * k + j] += v * pj;
                }
                if r != c {
                    for (j, pj) in p.row(r) {
                        w[c * k + j] += v * pj;
                    }
                }
            });
            let mut a = DMatrix::<f64>::zeros(k, k);
            for r in 0..n {
                for (i, pi) in p.row(r) {
                    for j in 0..k {
                        a[(i, j)] += pi * w[r * k + j];
                    }
                }
            }
            a
        };
        let bits = |m: &DMatrix<f64>| m.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        for s in [&sparse, &dense] {
            let expected = bits(&serial(s));
            assert!(expected.iter().any(|&b| f64::from_bits(b) != 0.0));
            for threads in [1, 2, 5] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let got = pool.install(|| coarse_matrix(s, &p, k));
                assert_eq!(bits(&got), expected, "{threads} threads");
            }
        }
    }

    /// Tiles cover the centres about `count` times, each centre in one, numbered densely.
    #[test]
    fn tiles_split_a_grid_of_centres_into_about_the_asked_count() {
        let centres: Vec<Vector3<f64>> = (0..40)
            .flat_map(|i| {
                (0..20).map(move |j| Vector3::new(i as f64 * 10.0, j as f64 * 10.0, 100.0))
            })
            .collect();
        let tile_of = tiles(&centres, 50);
        let count = tile_of.iter().max().unwrap() + 1;
        assert!((35..=80).contains(&count), "{count} tiles");
        let mut sizes = vec![0; count];
        for &t in &tile_of {
            sizes[t] += 1;
        }
        assert!(sizes.iter().all(|&s| s > 0));
        // Neighbours share a tile more often than far centres do.
        assert_eq!(tile_of[0], tile_of[1]);
        assert_ne!(tile_of[0], tile_of[centres.len() - 1]);
        // All at one place: one tile.
        assert_eq!(tiles(&[Vector3::new(1.0, 2.0, 3.0); 5], 3), vec![0; 5]);
    }
}
