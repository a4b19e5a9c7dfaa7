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
    pub query: u32,
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
    /// Largest accepted distance (Euclidean for unit-norm float descriptors, bits for binary).
    pub max_distance: Option<f32>,
}

impl Default for MatchOptions {
    fn default() -> Self {
        Self {
            ratio: 0.8,
            mutual: true,
            max_distance: None,
        }
    }
}

/// The two nearest neighbours found so far: (distance, index) pairs, best first.
#[derive(Debug, Clone, Copy)]
struct Nearest {
    best: f32,
    second: f32,
    index: u32,
}

impl Nearest {
    const EMPTY: Nearest = Nearest {
        best: f32::INFINITY,
        second: f32::INFINITY,
        index: u32::MAX,
    };

    #[inline]
    fn offer(&mut self, distance: f32, index: u32) {
        if distance < self.best {
            self.second = self.best;
            self.best = distance;
            self.index = index;
        } else if distance < self.second {
            self.second = distance;
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

    fn passes(&self, options: &MatchOptions) -> bool {
        self.index != u32::MAX
            && (options.ratio >= 1.0 || self.best < options.ratio * self.second)
            && options.max_distance.is_none_or(|m| self.best <= m)
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
            let norms_b: Vec<f32> = xb.chunks(*db).map(squared_norm).collect();
            let train = MatRef::from_column_major_slice(xb.as_slice(), *db, nb);
            (0..na.div_ceil(BLOCK))
                .into_par_iter()
                .map(|k| {
                    let rows = k * BLOCK..((k + 1) * BLOCK).min(na);
                    let query = MatRef::from_row_major_slice(
                        &xa[rows.start * da..rows.end * da],
                        rows.len(),
                        *da,
                    );
                    let mut products = faer::Mat::<f32>::zeros(rows.len(), nb);
                    faer::linalg::matmul::matmul(
                        products.as_mut(),
                        Accum::Replace,
                        query,
                        train,
                        1.0,
                        Par::Seq,
                    );
                    let norms_a: Vec<f32> = xa[rows.start * da..rows.end * da]
                        .chunks(*da)
                        .map(squared_norm)
                        .collect();
                    scan_block(rows.start, rows.len(), nb, |i, j| {
                        (norms_a[i] + norms_b[j] - 2.0 * products[(i, j)])
                            .max(0.0)
                            .sqrt()
                    })
                })
                .collect()
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
            let wa = to_words(xa, *ba);
            let wb = to_words(xb, *bb);
            let words = ba.div_ceil(8);
            (0..na.div_ceil(BLOCK))
                .into_par_iter()
                .map(|k| {
                    let rows = k * BLOCK..((k + 1) * BLOCK).min(na);
                    scan_block(rows.start, rows.len(), nb, |i, j| {
                        let qa = &wa[(rows.start + i) * words..(rows.start + i + 1) * words];
                        let qb = &wb[j * words..(j + 1) * words];
                        qa.iter()
                            .zip(qb)
                            .map(|(x, y)| (x ^ y).count_ones())
                            .sum::<u32>() as f32
                    })
                })
                .collect()
        }
        _ => return Err(incompatible()),
    };
    let mut columns = vec![Nearest::EMPTY; nb];
    for (_, block_columns) in &blocks {
        for (c, n) in columns.iter_mut().zip(block_columns) {
            c.merge(n);
        }
    }
    let mut matches = Vec::new();
    for (i, row) in blocks.iter().flat_map(|(rows, _)| rows).enumerate() {
        if !row.passes(options) {
            continue;
        }
        let j = row.index as usize;
        if options.mutual && !(columns[j].index as usize == i && columns[j].passes(options)) {
            continue;
        }
        matches.push(Match {
            query: i as u32,
            train: j as u32,
            distance: row.best,
        });
    }
    Ok(matches)
}

/// Two nearest train descriptors of each row of a block, and two nearest rows of the block for
/// each train descriptor (row indices offset by `first_row`).
fn scan_block(
    first_row: usize,
    rows: usize,
    train: usize,
    distance: impl Fn(usize, usize) -> f32,
) -> (Vec<Nearest>, Vec<Nearest>) {
    let mut by_row = vec![Nearest::EMPTY; rows];
    let mut by_column = vec![Nearest::EMPTY; train];
    for (i, row) in by_row.iter_mut().enumerate() {
        for (j, column) in by_column.iter_mut().enumerate() {
            let d = distance(i, j);
            row.offer(d, j as u32);
            column.offer(d, (first_row + i) as u32);
        }
    }
    (by_row, by_column)
}

fn squared_norm(v: &[f32]) -> f32 {
    v.iter().map(|x| x * x).sum()
}

/// Binary descriptors as little-endian 64-bit words, the last word of each zero-padded.
fn to_words(data: &[u8], bytes: usize) -> Vec<u64> {
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

fn describe(d: &Descriptors) -> String {
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
            max_distance: None,
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
            max_distance: None,
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
