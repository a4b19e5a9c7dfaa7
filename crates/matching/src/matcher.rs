//! Nearest-neighbour matching of descriptors, with Lowe's ratio test, a mutual (cross) check and
//! a maximum distance.
//!
//! Float descriptors are compared by Euclidean distance computed as ‖a‖² + ‖b‖² − 2 a·b, the
//! products taken block by block with faer's matrix multiplication (the exact nearest neighbours,
//! at the speed of a tuned GEMM); binary descriptors by Hamming distance over 64-bit words. Each
//! block of query rows yields its rows' two nearest train descriptors and, for the mutual check,
//! each train descriptor's two nearest among the block; blocks are merged in order, so results do
//! not depend on the thread count.

use faer::{Accum, MatRef, Par};
use rayon::prelude::*;
use timesift_core::Descriptors;

use crate::MatchingError;

/// Query rows per block: the distance block is `BLOCK × train` values.
const BLOCK: usize = 256;

/// A putative correspondence between keypoint `query` of the first image and keypoint `train` of
/// the second.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Match {
    /// Keypoint index in the first image.
    pub query: u32,
    /// Keypoint index in the second image.
    pub train: u32,
    /// Descriptor distance (Euclidean, or Hamming bits).
    pub distance: f32,
}

/// Options of [`match_descriptors`] (defaults: COLMAP's SIFT matching).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchOptions {
    /// Lowe's ratio: keep a match when the nearest distance is below `ratio` × the second
    /// nearest. 1 disables the test.
    pub ratio: f32,
    /// Keep a match only when each descriptor is the other's nearest neighbour, and the ratio
    /// test passes in both directions.
    pub mutual: bool,
    /// Largest accepted distance (in the units of `ratio_on`: radians for angles, bits for
    /// binary descriptors).
    pub max_distance: Option<f32>,
    /// What the ratio test and the maximum distance compare for float descriptors.
    pub ratio_on: FloatDistance,
}

/// The distance between float descriptors that the tests use. Nearest neighbours are the same
/// either way; the ratio differs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FloatDistance {
    /// Euclidean distance (Lowe 2004).
    Euclidean,
    /// Angle between unit-norm descriptors, radians (COLMAP): a looser ratio test for the same
    /// value, since the chord grows slower than the angle.
    Angle,
}

impl Default for MatchOptions {
    fn default() -> Self {
        Self {
            ratio: 0.8,
            mutual: true,
            max_distance: None,
            ratio_on: FloatDistance::Euclidean,
        }
    }
}

/// The two nearest neighbours found so far: (distance, index) pairs, best first.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Nearest {
    pub(crate) best: f32,
    pub(crate) second: f32,
    pub(crate) index: u32,
}

impl Nearest {
    pub(crate) const EMPTY: Nearest = Nearest {
        best: f32::INFINITY,
        second: f32::INFINITY,
        index: u32::MAX,
    };

    #[inline]
    pub(crate) fn offer(&mut self, distance: f32, index: u32) {
        if distance < self.best {
            self.second = self.best;
            self.best = distance;
            self.index = index;
        } else if distance < self.second {
            self.second = distance;
        }
    }

    /// Offers a (best, second, index) triple of another scan of disjoint candidates.
    #[inline]
    fn offer_pair(&mut self, best: f32, second: f32, index: u32) {
        if best < self.best || (best == self.best && index < self.index) {
            self.second = self.best.min(second);
            self.best = best;
            self.index = index;
        } else {
            self.second = self.second.min(best);
        }
    }

    fn merge(&mut self, other: &Nearest) {
        // Ties keep the earlier block's index: the lower query index, as one pass would.
        if other.best < self.best {
            self.second = self.best.min(other.second);
            self.best = other.best;
            self.index = other.index;
        } else {
            self.second = self.second.min(other.best);
        }
    }

    pub(crate) fn passes(&self, options: &MatchOptions, angles: bool) -> bool {
        // Chord of unit vectors → angle.
        let angle = |d: f32| 2.0 * (0.5 * d).min(1.0).asin();
        let (best, second) = if angles {
            (angle(self.best), angle(self.second))
        } else {
            (self.best, self.second)
        };
        self.index != u32::MAX
            && (options.ratio >= 1.0 || best < options.ratio * second)
            && options.max_distance.is_none_or(|m| best <= m)
    }
}

/// Matches descriptors `a` (queries) against `b` (train). Matches come ordered by query.
pub fn match_descriptors(
    a: &Descriptors,
    b: &Descriptors,
    options: &MatchOptions,
) -> Result<Vec<Match>, MatchingError> {
    if !(options.ratio > 0.0 && options.ratio <= 1.0) {
        return Err(MatchingError::InvalidOption {
            name: "ratio",
            value: options.ratio as f64,
            expected: "in (0, 1]",
        });
    }
    let incompatible = || MatchingError::IncompatibleDescriptors {
        a: describe(a),
        b: describe(b),
    };
    let (na, nb) = (a.len(), b.len());
    if na == 0 || nb == 0 {
        return Ok(Vec::new());
    }
    let blocks: Vec<(Vec<Nearest>, Vec<Nearest>)> = match (a, b) {
        (Descriptors::Float { dim: da, data: xa }, Descriptors::Float { dim: db, data: xb }) => {
            if da != db {
                return Err(incompatible());
            }
            float_blocks(xa, xb, *da, (na, nb))
        }
        (
            Descriptors::Binary {
                bytes: ba,
                data: xa,
            },
            Descriptors::Binary {
                bytes: bb,
                data: xb,
            },
        ) => {
            if ba != bb {
                return Err(incompatible());
            }
            binary_blocks(xa, xb, *ba, (na, nb))
        }
        _ => return Err(incompatible()),
    };
    let angles = options.ratio_on == FloatDistance::Angle && matches!(a, Descriptors::Float { .. });
    Ok(accepted_matches(&blocks, nb, options, angles))
}

/// The scan of every block of query rows of float descriptors (`d` values each) against the
/// train descriptors, by Euclidean distance from faer's matrix products; `(na, nb)` are the
/// descriptor counts.
fn float_blocks(
    xa: &[f32],
    xb: &[f32],
    d: usize,
    (na, nb): (usize, usize),
) -> Vec<(Vec<Nearest>, Vec<Nearest>)> {
    let norms_b: Vec<f32> = xb.chunks(d).map(squared_norm).collect();
    let train = MatRef::from_row_major_slice(xb, nb, d);
    (0..na.div_ceil(BLOCK))
        .into_par_iter()
        .map(|k| {
            let rows = k * BLOCK..((k + 1) * BLOCK).min(na);
            let block = &xa[rows.start * d..rows.end * d];
            // Column i of `products` (contiguous) holds query i's products with every train
            // descriptor.
            let queries = MatRef::from_column_major_slice(block, d, rows.len());
            let mut products = faer::Mat::<f32>::zeros(nb, rows.len());
            faer::linalg::matmul::matmul(
                products.as_mut(),
                Accum::Replace,
                train,
                queries,
                1.0,
                Par::Seq,
            );
            let norms_a: Vec<f32> = block.chunks(d).map(squared_norm).collect();
            scan_block(rows.start, rows.len(), nb, |i, out| {
                // Squared distance ‖a‖² + ‖b‖² − 2 a·b.
                let column = products.col(i);
                let na_i = norms_a[i];
                for ((o, nbj), j) in out.iter_mut().zip(&norms_b).zip(0..nb) {
                    *o = na_i + nbj - 2.0 * column[j];
                }
            })
        })
        .collect()
}

/// The scan of every block of query rows of binary descriptors (`bytes` each) against the
/// train descriptors, by Hamming distance over 64-bit words; `(na, nb)` are the descriptor
/// counts.
fn binary_blocks(
    xa: &[u8],
    xb: &[u8],
    bytes: usize,
    (na, nb): (usize, usize),
) -> Vec<(Vec<Nearest>, Vec<Nearest>)> {
    let wa = to_words(xa, bytes);
    let wb = to_words(xb, bytes);
    let words = bytes.div_ceil(8);
    (0..na.div_ceil(BLOCK))
        .into_par_iter()
        .map(|k| {
            let rows = k * BLOCK..((k + 1) * BLOCK).min(na);
            scan_block(rows.start, rows.len(), nb, |i, out| {
                let qa = &wa[(rows.start + i) * words..(rows.start + i + 1) * words];
                for (o, qb) in out.iter_mut().zip(wb.chunks(words)) {
                    *o = squared_hamming(qa, qb);
                }
            })
        })
        .collect()
}

/// The matches of the blocks' rows that pass the ratio test and maximum distance (and, when
/// asked, the mutual check against the columns merged over all blocks), ordered by query.
fn accepted_matches(
    blocks: &[(Vec<Nearest>, Vec<Nearest>)],
    nb: usize,
    options: &MatchOptions,
    angles: bool,
) -> Vec<Match> {
    let mut columns = vec![Nearest::EMPTY; nb];
    for (_, block_columns) in blocks {
        for (c, n) in columns.iter_mut().zip(block_columns) {
            c.merge(n);
        }
    }
    let mut matches = Vec::new();
    for (i, row) in blocks.iter().flat_map(|(rows, _)| rows).enumerate() {
        if !row.passes(options, angles) {
            continue;
        }
        let j = row.index as usize;
        if options.mutual && !(columns[j].index as usize == i && columns[j].passes(options, angles))
        {
            continue;
        }
        matches.push(Match {
            query: i as u32,
            train: j as u32,
            distance: row.best,
        });
    }
    matches
}

/// Lanes of the row scan: independent running top-2s that vectorise, merged at the end.
const LANES: usize = 16;

/// Two nearest train descriptors of each row of a block, and two nearest rows of the block for
/// each train descriptor (row indices offset by `first_row`). `squared(i, out)` writes row i's
/// squared distances to every train descriptor into `out`. Distances come back as Euclidean
/// (square roots), for the ratio test.
fn scan_block(
    first_row: usize,
    rows: usize,
    train: usize,
    mut squared: impl FnMut(usize, &mut [f32]),
) -> (Vec<Nearest>, Vec<Nearest>) {
    let mut by_row = vec![Nearest::EMPTY; rows];
    let mut column_best = vec![f32::INFINITY; train];
    let mut column_second = vec![f32::INFINITY; train];
    let mut column_index = vec![u32::MAX; train];
    let mut distances = vec![0.0f32; train];
    for (i, row) in by_row.iter_mut().enumerate() {
        squared(i, &mut distances);
        *row = row_top2(&distances);
        update_columns(
            &distances,
            (first_row + i) as u32,
            &mut column_best,
            &mut column_second,
            &mut column_index,
        );
    }
    let by_column = (0..train)
        .map(|j| Nearest {
            best: column_best[j].max(0.0).sqrt(),
            second: column_second[j].max(0.0).sqrt(),
            index: column_index[j],
        })
        .collect();
    (by_row, by_column)
}

/// The two smallest values of `row` (as square roots) and the index of the smallest.
fn row_top2(row: &[f32]) -> Nearest {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        return unsafe { row_top2_avx2(row) };
    }
    row_top2_portable(row)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn row_top2_avx2(row: &[f32]) -> Nearest {
    row_top2_portable(row)
}

#[inline(always)]
fn row_top2_portable(row: &[f32]) -> Nearest {
    let mut best = [f32::INFINITY; LANES];
    let mut second = [f32::INFINITY; LANES];
    let mut index = [u32::MAX; LANES];
    let chunks = row.len() / LANES;
    for c in 0..chunks {
        let values = &row[c * LANES..(c + 1) * LANES];
        for l in 0..LANES {
            let v = values[l];
            let smaller = v < best[l];
            second[l] = second[l].min(if v > best[l] { v } else { best[l] });
            index[l] = if smaller {
                (c * LANES + l) as u32
            } else {
                index[l]
            };
            best[l] = if smaller { v } else { best[l] };
        }
    }
    let mut out = Nearest::EMPTY;
    for l in 0..LANES {
        // Lane bests in increasing index order within equal values: offer keeps the first.
        out.offer_pair(best[l], second[l], index[l]);
    }
    for (j, &v) in row.iter().enumerate().skip(chunks * LANES) {
        out.offer(v, j as u32);
    }
    Nearest {
        best: out.best.max(0.0).sqrt(),
        second: out.second.max(0.0).sqrt(),
        index: out.index,
    }
}

/// Offers row `i`'s squared distances to every column's running top-2.
fn update_columns(row: &[f32], i: u32, best: &mut [f32], second: &mut [f32], index: &mut [u32]) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        return unsafe { update_columns_avx2(row, i, best, second, index) };
    }
    update_columns_portable(row, i, best, second, index)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn update_columns_avx2(
    row: &[f32],
    i: u32,
    best: &mut [f32],
    second: &mut [f32],
    index: &mut [u32],
) {
    update_columns_portable(row, i, best, second, index)
}

#[inline(always)]
fn update_columns_portable(
    row: &[f32],
    i: u32,
    best: &mut [f32],
    second: &mut [f32],
    index: &mut [u32],
) {
    let n = row.len();
    let (best, second, index) = (&mut best[..n], &mut second[..n], &mut index[..n]);
    for j in 0..n {
        let v = row[j];
        let smaller = v < best[j];
        second[j] = second[j].min(if v > best[j] { v } else { best[j] });
        index[j] = if smaller { i } else { index[j] };
        best[j] = if smaller { v } else { best[j] };
    }
}

fn squared_norm(v: &[f32]) -> f32 {
    v.iter().map(|x| x * x).sum()
}

/// Squared Hamming distance of two binary descriptors held as words: squared, like the float
/// distances, so that one scan (and [`Nearest`]) serves both.
#[inline]
pub(crate) fn squared_hamming(a: &[u64], b: &[u64]) -> f32 {
    let bits = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x ^ y).count_ones())
        .sum::<u32>() as f32;
    bits * bits
}

/// Binary descriptors as little-endian 64-bit words, the last word of each zero-padded.
pub(crate) fn to_words(data: &[u8], bytes: usize) -> Vec<u64> {
    let words = bytes.div_ceil(8);
    let mut out = Vec::with_capacity(data.len() / bytes.max(1) * words);
    for d in data.chunks(bytes) {
        for w in d.chunks(8) {
            let mut buf = [0u8; 8];
            buf[..w.len()].copy_from_slice(w);
            out.push(u64::from_le_bytes(buf));
        }
    }
    out
}

pub(crate) fn describe(d: &Descriptors) -> String {
    match d {
        Descriptors::Float { dim, .. } => format!("{dim}-D float"),
        Descriptors::Binary { bytes, .. } => format!("{bytes}-byte binary"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn float(rows: &[[f32; 4]]) -> Descriptors {
        Descriptors::Float {
            dim: 4,
            data: rows.iter().flatten().copied().collect(),
        }
    }

    #[test]
    fn ratio_and_mutual_logic() {
        // a0 is close to b0 only; a1 is equally close to b1 and b2 (ambiguous); a2 and a3 both
        // prefer b3, a3 more so.
        let a = float(&[
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.9, 0.1],
        ]);
        let b = float(&[
            [0.98, 0.02, 0.0, 0.0],
            [0.1, 0.9, 0.1, 0.0],
            [-0.1, 0.9, 0.1, 0.0],
            [0.0, 0.0, 0.93, 0.09],
        ]);
        let plain = MatchOptions {
            ratio: 1.0,
            mutual: false,
            ..MatchOptions::default()
        };
        let all = match_descriptors(&a, &b, &plain).unwrap();
        assert_eq!(all.len(), 4);
        assert_eq!(
            all.iter().map(|m| (m.query, m.train)).collect::<Vec<_>>(),
            vec![(0, 0), (1, 1), (2, 3), (3, 3)]
        );
        // Ratio 0.8 drops the ambiguous a1 (its two distances are equal).
        let ratio = MatchOptions {
            ratio: 0.8,
            ..plain
        };
        let kept: Vec<_> = match_descriptors(&a, &b, &ratio)
            .unwrap()
            .iter()
            .map(|m| m.query)
            .collect();
        assert!(!kept.contains(&1));
        assert!(kept.contains(&0));
        // Mutual: b3's nearest query is a3, so a2 → b3 goes.
        let mutual = MatchOptions {
            ratio: 1.0,
            mutual: true,
            ..MatchOptions::default()
        };
        let kept: Vec<_> = match_descriptors(&a, &b, &mutual)
            .unwrap()
            .iter()
            .map(|m| (m.query, m.train))
            .collect();
        assert!(kept.contains(&(3, 3)) && !kept.contains(&(2, 3)));
        // Maximum distance.
        let near = MatchOptions {
            max_distance: Some(0.03),
            ..plain
        };
        let kept = match_descriptors(&a, &b, &near).unwrap();
        assert_eq!(kept.len(), 1);
        assert_eq!((kept[0].query, kept[0].train), (0, 0));
        assert!((kept[0].distance - (0.02f32 * 0.02 * 2.0).sqrt()).abs() < 1e-5);
    }

    #[test]
    fn hamming_matching_and_incompatible_kinds() {
        let a = Descriptors::Binary {
            bytes: 9,
            data: vec![0xff; 9].into_iter().chain(vec![0x00; 9]).collect(),
        };
        let mut b_data = vec![0x00; 9];
        b_data[8] = 0x01;
        b_data.extend(vec![0xff; 9]);
        b_data[17] = 0x7f;
        let b = Descriptors::Binary {
            bytes: 9,
            data: b_data,
        };
        let m = match_descriptors(&a, &b, &MatchOptions::default()).unwrap();
        assert_eq!(m.len(), 2);
        assert_eq!((m[0].query, m[0].train, m[0].distance), (0, 1, 1.0));
        assert_eq!((m[1].query, m[1].train, m[1].distance), (1, 0, 1.0));
        let f = float(&[[1.0, 0.0, 0.0, 0.0]]);
        let err = match_descriptors(&a, &f, &MatchOptions::default()).unwrap_err();
        assert!(err.to_string().contains("9-byte binary"), "{err}");
    }

    #[test]
    fn blocks_do_not_change_the_result() {
        // More queries than a block, with an exact duplicate pair across the block boundary.
        let mut rng = timesift_core::SeededRng::new(5);
        let dim = 16;
        let n = BLOCK * 2 + 17;
        let data: Vec<f32> = (0..n * dim)
            .map(|_| rng.uniform_range(-1.0, 1.0) as f32)
            .collect();
        let a = Descriptors::Float {
            dim,
            data: data.clone(),
        };
        // b: a shuffled copy with small noise.
        let order: Vec<usize> = (0..n).map(|i| (i * 7919) % n).collect();
        let b_data: Vec<f32> = order
            .iter()
            .flat_map(|&i| data[i * dim..(i + 1) * dim].to_vec())
            .map(|v| v + rng.uniform_range(-0.01, 0.01) as f32)
            .collect();
        let b = Descriptors::Float { dim, data: b_data };
        let m = match_descriptors(&a, &b, &MatchOptions::default()).unwrap();
        assert_eq!(m.len(), n);
        for x in &m {
            assert_eq!(order[x.train as usize], x.query as usize);
        }
    }
}
