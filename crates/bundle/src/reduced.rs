//! Storage of the reduced camera system `S`: dense for small problems, or sparse (lower triangle,
//! compressed columns) with a symbolic Cholesky analysis computed once per solve and a numeric
//! factorisation per trial step (faer).

use std::sync::Arc;

use faer::Side;
use faer::sparse::linalg::solvers::{Llt, SymbolicLlt};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use nalgebra::{DMatrix, DVector};

/// The fixed sparsity pattern of `S` (lower triangle) and its symbolic factorisation.
#[derive(Clone)]
pub(crate) struct SparsePattern {
    n: usize,
    pub(crate) col_ptr: Vec<usize>,
    pub(crate) row_idx: Vec<usize>,
    /// `None` for patterns used only for products (the iterative solver).
    symbolic: Option<SymbolicLlt<usize>>,
    /// Where each column's run of a block's rows starts, without a search ([`BlockIndex`]).
    blocks: Option<BlockIndex>,
    /// Column runs of about equal stored entries, one task each in [`Reduced::mul_vec_into`]
    /// ([`PRODUCT_PARTS`] of them, whatever the threads: the partial sums, and so the bits,
    /// depend on the pattern alone).
    product_runs: Vec<usize>,
}

/// Parts of the parallel product with a sparse `S`.
const PRODUCT_PARTS: usize = 8;

/// The pattern's blocks and, per pair of coupled blocks (A below or at B), where A's rows start
/// among the rows every column of B holds below B itself. The pattern is built block by block,
/// so the entry (r, c) of block pair (A, B) sits at a position known from these alone; the
/// elimination adds some (6k)²/2 runs per point seen k times, and finding each by a binary
/// search through a column of thousands of rows was most of its time on multi-epoch blocks of
/// 1,600 images.
#[derive(Clone)]
struct BlockIndex {
    /// Block of each column.
    block_of: Vec<u32>,
    /// First column of each block, and the end.
    starts: Vec<usize>,
    /// Per pair (A ≥ B) at `A (A + 1) / 2 + B`: A's first row's position among B's rows below
    /// B, or `u32::MAX` where A and B are not coupled (and on the diagonal).
    below: Vec<u32>,
}

/// Most blocks for which the pattern keeps a [`BlockIndex`] (its pair table grows with their
/// square: 4 bytes per pair, 200 MB at this many).
const MAX_INDEXED_BLOCKS: usize = 10_000;

impl SparsePattern {
    /// Builds the pattern from the sets of camera-side columns that interact (each set couples all
    /// its columns); the diagonal is always present.
    /// `factorise`: run the symbolic Cholesky analysis (not needed by the iterative solver).
    ///
    /// Columns come in blocks that every set holds whole or not at all (a pose's six, an
    /// intrinsics group's), so the coupling is found between blocks and only then spread to
    /// their columns: a point seen in k images couples about k²/2 blocks but (6k)²/2 columns,
    /// and sorting the latter was most of an adjustment's time on blocks of hundreds of images.
    /// The pattern is the same as the column-by-column one.
    pub(crate) fn new(n: usize, groups: &[Vec<usize>], factorise: bool) -> Option<Arc<Self>> {
        let sorted: Vec<Vec<usize>> = groups
            .iter()
            .map(|g| {
                let mut g = g.clone();
                g.sort_unstable();
                g.dedup();
                g
            })
            .collect();
        // A block boundary wherever some set's run of consecutive columns starts or ends; a
        // column of no set is a block of its own.
        let mut cut = vec![false; n + 1];
        let mut used = vec![false; n];
        cut[0] = true;
        cut[n] = true;
        for g in &sorted {
            for (k, &c) in g.iter().enumerate() {
                if c >= n {
                    return None;
                }
                used[c] = true;
                if k == 0 || g[k - 1] + 1 != c {
                    cut[c] = true;
                }
                if k + 1 == g.len() || g[k + 1] != c + 1 {
                    cut[c + 1] = true;
                }
            }
        }
        for (c, u) in used.iter().enumerate() {
            if !u {
                cut[c] = true;
                cut[c + 1] = true;
            }
        }
        let starts: Vec<usize> = (0..=n).filter(|&c| cut[c]).collect();
        let blocks = starts.len() - 1;
        let mut block_of = vec![0usize; n];
        for b in 0..blocks {
            block_of[starts[b]..starts[b + 1]].fill(b);
        }
        let mut coupled: Vec<Vec<usize>> = vec![Vec::new(); blocks];
        let mut ids = Vec::new();
        for g in &sorted {
            ids.clear();
            ids.extend(g.iter().map(|&c| block_of[c]));
            ids.dedup();
            for (i, &b) in ids.iter().enumerate() {
                coupled[b].extend_from_slice(&ids[i + 1..]);
            }
        }
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::new();
        col_ptr.push(0);
        let mut below = Vec::new();
        let indexed = blocks <= MAX_INDEXED_BLOCKS;
        let mut pairs = if indexed {
            vec![u32::MAX; blocks * (blocks + 1) / 2]
        } else {
            Vec::new()
        };
        for (b, later) in coupled.iter_mut().enumerate() {
            later.sort_unstable();
            later.dedup();
            below.clear();
            for &a in later.iter() {
                if indexed {
                    pairs[a * (a + 1) / 2 + b] = u32::try_from(below.len()).unwrap_or(u32::MAX);
                }
                below.extend(starts[a]..starts[a + 1]);
            }
            for c in starts[b]..starts[b + 1] {
                row_idx.extend(c..starts[b + 1]);
                row_idx.extend_from_slice(&below);
                col_ptr.push(row_idx.len());
            }
        }
        let symbolic = if factorise {
            Some(
                SymbolicLlt::try_new(
                    SymbolicSparseColMatRef::new_checked(n, n, &col_ptr, None, &row_idx),
                    Side::Lower,
                )
                .ok()?,
            )
        } else {
            None
        };
        let blocks = indexed.then(|| BlockIndex {
            block_of: block_of.iter().map(|&b| b as u32).collect(),
            starts,
            below: pairs,
        });
        let mut pattern = SparsePattern {
            n,
            col_ptr,
            row_idx,
            symbolic,
            blocks,
            product_runs: Vec::new(),
        };
        pattern.product_runs = pattern.column_runs(PRODUCT_PARTS);
        Some(Arc::new(pattern))
    }

    /// Where row `row` (≥ `col`) of column `col` is held among the column's stored rows, found
    /// from the block index without a search; `None` without an index or when the blocks of
    /// `row` and `col` are not coupled (the caller then searches, or skips it). Within a pair
    /// of coupled blocks every entry is stored (the pattern couples whole blocks), so the
    /// position is the entry's.
    #[inline]
    pub(crate) fn position_in_column(&self, col: usize, row: usize) -> Option<usize> {
        let index = self.blocks.as_ref()?;
        let (b, a) = (index.block_of[col] as usize, index.block_of[row] as usize);
        let k = if a == b {
            row - col
        } else {
            let start = *index.below.get(a * (a + 1) / 2 + b)?;
            if start == u32::MAX {
                return None;
            }
            index.starts[b + 1] - col + start as usize + (row - index.starts[a])
        };
        // Within the column, and (checked in tests and debug builds only: reading the row index
        // back was one of the two cache misses of each run on large systems) the row it names.
        let len = self.col_ptr[col + 1] - self.col_ptr[col];
        debug_assert!(k >= len || self.row_idx[self.col_ptr[col] + k] == row);
        (k < len).then_some(k)
    }

    /// The same pattern with its symbolic Cholesky analysis (for a pattern built without it,
    /// once the solver has decided to factorise); `None` when the analysis fails.
    pub(crate) fn analysed(self: Arc<Self>) -> Option<Arc<Self>> {
        if self.symbolic.is_some() {
            return Some(self);
        }
        let mut pattern = Arc::try_unwrap(self).unwrap_or_else(|shared| (*shared).clone());
        pattern.symbolic = Some(
            SymbolicLlt::try_new(
                SymbolicSparseColMatRef::new_checked(
                    pattern.n,
                    pattern.n,
                    &pattern.col_ptr,
                    None,
                    &pattern.row_idx,
                ),
                Side::Lower,
            )
            .ok()?,
        );
        Some(Arc::new(pattern))
    }

    /// Stored entries (lower triangle with the diagonal).
    pub(crate) fn nnz_lower(&self) -> usize {
        self.row_idx.len()
    }

    /// Column boundaries `0 = c_0 < … < c_k = n` splitting the stored entries into at most
    /// `parts` runs of about equal size.
    fn column_runs(&self, parts: usize) -> Vec<usize> {
        let per = self.nnz_lower().div_ceil(parts.max(1)).max(1);
        let mut cuts = vec![0usize];
        for c in 0..self.n {
            if self.col_ptr[c + 1] - self.col_ptr[cuts[cuts.len() - 1]] >= per {
                cuts.push(c + 1);
            }
        }
        if cuts[cuts.len() - 1] != self.n {
            cuts.push(self.n);
        }
        cuts
    }

    /// Where entry (row, col) of the lower triangle (either order) is stored. Why the block
    /// index first: the linearisation adds each observation's `JᵀJ` entry by entry, and a
    /// binary search through columns of thousands of rows per entry was a fifth of the align
    /// stage's time on 1,600 images.
    fn slot(&self, row: usize, col: usize) -> Option<usize> {
        let (r, c) = if row >= col { (row, col) } else { (col, row) };
        let start = self.col_ptr[c];
        if self.blocks.is_some() {
            return self.position_in_column(c, r).map(|k| start + k);
        }
        let rows = &self.row_idx[start..self.col_ptr[c + 1]];
        rows.binary_search(&r).ok().map(|k| start + k)
    }
}

/// `S` in one of its two storages.
#[derive(Clone)]
pub(crate) enum Reduced {
    Dense(DMatrix<f64>),
    Sparse {
        pattern: Arc<SparsePattern>,
        values: Vec<f64>,
    },
}

impl Reduced {
    pub(crate) fn dense(n: usize) -> Self {
        Reduced::Dense(DMatrix::zeros(n, n))
    }

    /// Every value zero, the storage kept.
    pub(crate) fn clear(&mut self) {
        match self {
            Reduced::Dense(m) => m.fill(0.0),
            Reduced::Sparse { values, .. } => values.fill(0.0),
        }
    }

    /// Becomes a copy of `other`, reusing this storage when the two have the same shape.
    pub(crate) fn assign(&mut self, other: &Reduced) {
        match (&mut *self, other) {
            (Reduced::Dense(m), Reduced::Dense(o)) if m.shape() == o.shape() => m.copy_from(o),
            (
                Reduced::Sparse { pattern, values },
                Reduced::Sparse {
                    pattern: op,
                    values: ov,
                },
            ) if Arc::ptr_eq(pattern, op) => values.copy_from_slice(ov),
            _ => *self = other.clone(),
        }
    }

    pub(crate) fn sparse(pattern: Arc<SparsePattern>) -> Self {
        let values = vec![0.0; pattern.row_idx.len()];
        Reduced::Sparse { pattern, values }
    }

    /// Adds `v` at (row, col). For the sparse storage, which keeps the lower triangle of a
    /// symmetric matrix, entries above the diagonal are ignored: callers add both halves.
    #[inline]
    pub(crate) fn add(&mut self, row: usize, col: usize, v: f64) {
        match self {
            Reduced::Dense(m) => {
                let n = m.nrows();
                m.as_mut_slice()[row + col * n] += v;
            }
            Reduced::Sparse { pattern, values } => {
                if row >= col {
                    if let Some(k) = pattern.slot(row, col) {
                        values[k] += v;
                    }
                }
            }
        }
    }

    /// Entry (row, col) of the symmetric matrix.
    pub(crate) fn get(&self, row: usize, col: usize) -> f64 {
        match self {
            Reduced::Dense(m) => m[(row, col)],
            Reduced::Sparse { pattern, values } => {
                pattern.slot(row, col).map_or(0.0, |k| values[k])
            }
        }
    }

    /// `y = S x` (the sparse storage holds the lower triangle of a symmetric matrix).
    pub(crate) fn mul_vec(&self, x: &DVector<f64>) -> DVector<f64> {
        match self {
            Reduced::Dense(m) => m * x,
            Reduced::Sparse { pattern, values } => {
                let mut y = DVector::zeros(x.len());
                for c in 0..pattern.n {
                    for k in pattern.col_ptr[c]..pattern.col_ptr[c + 1] {
                        let r = pattern.row_idx[k];
                        y[r] += values[k] * x[c];
                        if r != c {
                            y[c] += values[k] * x[r];
                        }
                    }
                }
                y
            }
        }
    }

    /// `y = S x` into `y` (the conjugate gradients' product, hundreds of times per step).
    /// The sparse storage's columns are split into the pattern's runs of about equal stored
    /// entries (fixed by the pattern, so the bits do not depend on the threads), each adding
    /// into its own part of `scratch` (kept by the caller across products), summed in order.
    pub(crate) fn mul_vec_into(&self, x: &[f64], y: &mut [f64], scratch: &mut Vec<f64>) {
        use rayon::prelude::*;
        match self {
            Reduced::Dense(m) => {
                let n = m.nrows();
                y.par_iter_mut().enumerate().for_each(|(r, y)| {
                    // Column r of the symmetric matrix is its row r.
                    let col = &m.as_slice()[r * n..(r + 1) * n];
                    *y = col.iter().zip(x).map(|(a, b)| a * b).sum();
                });
            }
            Reduced::Sparse { pattern, values } => {
                let n = pattern.n;
                let runs = &pattern.product_runs;
                let lower_times = |c0: usize, c1: usize, out: &mut [f64]| {
                    out.fill(0.0);
                    for c in c0..c1 {
                        let (mut acc, xc) = (0.0, x[c]);
                        for k in pattern.col_ptr[c]..pattern.col_ptr[c + 1] {
                            let r = pattern.row_idx[k];
                            let v = values[k];
                            out[r] += v * xc;
                            if r != c {
                                acc += v * x[r];
                            }
                        }
                        out[c] += acc;
                    }
                };
                if runs.len() <= 2 {
                    lower_times(0, n, y);
                    return;
                }
                scratch.resize((runs.len() - 1) * n, 0.0);
                scratch
                    .par_chunks_mut(n)
                    .zip(runs.par_windows(2))
                    .for_each(|(out, w)| lower_times(w[0], w[1], out));
                y.fill(0.0);
                for out in scratch.chunks(n) {
                    for (y, v) in y.iter_mut().zip(out) {
                        *y += v;
                    }
                }
            }
        }
    }

    /// Calls `f(row, col, value)`, column by column and down each column, for every stored entry
    /// that rows `rows` of a product with the symmetric matrix read: those of columns before
    /// `rows` whose row is in it, and every entry of the columns in it. Why: tasks that each own
    /// a band of a product's rows then sum every row's terms in the serial order.
    pub(crate) fn for_each_lower_touching(
        &self,
        rows: std::ops::Range<usize>,
        mut f: impl FnMut(usize, usize, f64),
    ) {
        match self {
            Reduced::Dense(m) => {
                for c in 0..rows.end.min(m.ncols()) {
                    let from = if c < rows.start { rows.start } else { c };
                    let to = if c < rows.start { rows.end } else { m.nrows() };
                    for r in from..to {
                        f(r, c, m[(r, c)]);
                    }
                }
            }
            Reduced::Sparse { pattern, values } => {
                for c in 0..rows.end.min(pattern.n) {
                    let (lo, hi) = (pattern.col_ptr[c], pattern.col_ptr[c + 1]);
                    let column = &pattern.row_idx[lo..hi];
                    let (from, to) = if c < rows.start {
                        (
                            column.partition_point(|&r| r < rows.start),
                            column.partition_point(|&r| r < rows.end),
                        )
                    } else {
                        (0, column.len())
                    };
                    for k in lo + from..lo + to {
                        f(pattern.row_idx[k], c, values[k]);
                    }
                }
            }
        }
    }

    /// The stored rows at or below `from` of column `col` and their values (for the sparse
    /// storage; every row of the dense one).
    pub(crate) fn column_tail(&self, col: usize, from: usize) -> Vec<(usize, f64)> {
        match self {
            Reduced::Dense(m) => (from.max(col)..m.nrows())
                .map(|r| (r, m[(r, col)]))
                .collect(),
            Reduced::Sparse { pattern, values } => {
                let (lo, hi) = (pattern.col_ptr[col], pattern.col_ptr[col + 1]);
                let rows = &pattern.row_idx[lo..hi];
                let start = rows.partition_point(|&r| r < from);
                (start..rows.len())
                    .map(|k| (rows[k], values[lo + k]))
                    .collect()
            }
        }
    }

    pub(crate) fn diagonal(&self, i: usize) -> f64 {
        match self {
            Reduced::Dense(m) => m[(i, i)],
            Reduced::Sparse { pattern, values } => pattern.slot(i, i).map_or(0.0, |k| values[k]),
        }
    }

    /// The Cholesky factorisation of `S`, to solve against as many right-hand sides as needed
    /// ([`Factor`]); `None` when `S` is not positive definite.
    pub(crate) fn factor(&self) -> Option<Factor> {
        match self {
            Reduced::Dense(m) => {
                let n = m.nrows();
                let fm = faer::Mat::<f64>::from_fn(n, n, |i, j| m[(i, j)]);
                Some(Factor::Dense(fm.llt(Side::Lower).ok()?))
            }
            Reduced::Sparse { pattern, values } => {
                let sym = SymbolicSparseColMatRef::new_checked(
                    pattern.n,
                    pattern.n,
                    &pattern.col_ptr,
                    None,
                    &pattern.row_idx,
                );
                let mat = SparseColMatRef::new(sym, values);
                let llt =
                    Llt::try_new_with_symbolic(pattern.symbolic.clone()?, mat, Side::Lower).ok()?;
                Some(Factor::Sparse(llt, pattern.n))
            }
        }
    }

    /// Solves `S x = b` by Cholesky; `None` when `S` is not positive definite.
    pub(crate) fn solve(&self, b: &DVector<f64>) -> Option<DVector<f64>> {
        self.factor()?.solve(b)
    }
}

/// A Cholesky factorisation of `S`. Covariances need many columns of `S⁻¹` (every pose's block,
/// the offsets', the rigid motions'): each is a solve against one factorisation, never a new
/// factorisation, which on a block of hundreds of images costs as much as an iteration.
pub(crate) enum Factor {
    Dense(faer::linalg::solvers::Llt<f64>),
    /// The factorisation and the order of `S`.
    Sparse(Llt<usize, f64>, usize),
}

impl Factor {
    /// Order of `S`.
    pub(crate) fn n(&self) -> usize {
        match self {
            Factor::Dense(llt) => llt.L().nrows(),
            Factor::Sparse(_, n) => *n,
        }
    }

    /// Solves `S X = B` in place for the columns of `rhs`; `None` when a result is not finite.
    pub(crate) fn solve_in_place(&self, rhs: &mut faer::Mat<f64>) -> Option<()> {
        use faer::prelude::Solve;
        match self {
            Factor::Dense(llt) => llt.solve_in_place(rhs.as_mut()),
            Factor::Sparse(llt, _) => llt.solve_in_place(rhs.as_mut()),
        }
        (0..rhs.ncols())
            .all(|k| (0..rhs.nrows()).all(|i| rhs[(i, k)].is_finite()))
            .then_some(())
    }

    /// Solves `S x = b`; `None` when the result is not finite.
    pub(crate) fn solve(&self, b: &DVector<f64>) -> Option<DVector<f64>> {
        let n = b.len();
        let mut x = faer::Mat::<f64>::from_fn(n, 1, |i, _| b[i]);
        self.solve_in_place(&mut x)?;
        Some(DVector::from_fn(n, |i, _| x[(i, 0)]))
    }

    /// Columns `columns` of the inverse (n × columns.len()), or `None` when a solve fails.
    pub(crate) fn inverse_columns(&self, columns: &[usize]) -> Option<faer::Mat<f64>> {
        let mut rhs = faer::Mat::<f64>::zeros(self.n(), columns.len());
        for (k, &c) in columns.iter().enumerate() {
            rhs[(c, k)] = 1.0;
        }
        self.solve_in_place(&mut rhs)?;
        Some(rhs)
    }

    /// Diagonal blocks `(start, len)` of `S⁻¹`, by solves against the identity columns of the
    /// blocks in batches of [`INVERSE_BATCH`] columns, so that memory stays at n × batch;
    /// `None` when a solve fails.
    pub(crate) fn inverse_diagonal_blocks(
        &self,
        blocks: &[(usize, usize)],
    ) -> Option<Vec<DMatrix<f64>>> {
        // (column of S, block, column within the block)
        let columns: Vec<(usize, usize, usize)> = blocks
            .iter()
            .enumerate()
            .flat_map(|(b, &(s, l))| (0..l).map(move |j| (s + j, b, j)))
            .collect();
        let mut out: Vec<DMatrix<f64>> =
            blocks.iter().map(|&(_, l)| DMatrix::zeros(l, l)).collect();
        for chunk in columns.chunks(INVERSE_BATCH) {
            let solved = self.inverse_columns(&chunk.iter().map(|c| c.0).collect::<Vec<_>>())?;
            for (k, &(_, b, j)) in chunk.iter().enumerate() {
                let (start, len) = blocks[b];
                for i in 0..len {
                    out[b][(i, j)] = solved[(start + i, k)];
                }
            }
        }
        Some(out)
    }
}

/// Columns of `S⁻¹` solved at once by [`Factor::inverse_diagonal_blocks`].
const INVERSE_BATCH: usize = 256;

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use nalgebra::DVector;

    use super::{Reduced, SparsePattern};

    /// The pattern column by column: every pair of columns of every set.
    fn column_by_column(n: usize, groups: &[Vec<usize>]) -> (Vec<usize>, Vec<usize>) {
        let mut rows: Vec<Vec<usize>> = (0..n).map(|c| vec![c]).collect();
        for g in groups {
            for &a in g {
                for &b in g {
                    if a >= b {
                        rows[b].push(a);
                    }
                }
            }
        }
        let mut col_ptr = vec![0];
        let mut row_idx = Vec::new();
        for r in &mut rows {
            r.sort_unstable();
            r.dedup();
            row_idx.extend_from_slice(r);
            col_ptr.push(row_idx.len());
        }
        (col_ptr, row_idx)
    }

    proptest! {
        /// Sets made of whole blocks of a random partition (as a bundle problem's are: poses,
        /// intrinsics groups, offsets), some columns in no set: the block-wise pattern is the
        /// column-by-column one.
        #[test]
        fn the_blockwise_pattern_is_the_column_by_column_one(
            widths in prop::collection::vec(1usize..8, 1..30),
            picks in prop::collection::vec(prop::collection::vec(any::<prop::sample::Index>(), 1..6), 0..40),
        ) {
            let starts: Vec<usize> = std::iter::once(0)
                .chain(widths.iter().scan(0, |s, w| { *s += w; Some(*s) }))
                .collect();
            let n = *starts.last().unwrap();
            // The last block is in no set.
            let blocks = widths.len().saturating_sub(1).max(1);
            let groups: Vec<Vec<usize>> = picks
                .iter()
                .map(|p| {
                    p.iter()
                        .flat_map(|i| {
                            let b = i.index(blocks);
                            starts[b]..starts[b + 1]
                        })
                        .collect()
                })
                .collect();
            let pattern = SparsePattern::new(n, &groups, true).unwrap();
            let (col_ptr, row_idx) = column_by_column(n, &groups);
            prop_assert_eq!(&pattern.col_ptr, &col_ptr);
            prop_assert_eq!(&pattern.row_idx, &row_idx);
            // The block index finds every stored entry where it is, and no entry that is not.
            for c in 0..n {
                let rows = &row_idx[col_ptr[c]..col_ptr[c + 1]];
                for r in c..n {
                    let want = rows.binary_search(&r).ok();
                    prop_assert_eq!(pattern.position_in_column(c, r), want, "({}, {})", r, c);
                }
            }
        }
    }

    proptest! {
        /// The workers' product with the sparse lower triangle equals the serial one and the
        /// product with the same matrix stored densely (both halves), whatever the pattern.
        #[test]
        fn the_parallel_product_is_the_symmetric_product(
            n in 1usize..40,
            picks in prop::collection::vec(prop::collection::vec(0usize..40, 1..6), 0..30),
            seed in any::<u64>(),
        ) {
            let groups: Vec<Vec<usize>> = picks
                .iter()
                .map(|g| g.iter().map(|&c| c % n).collect())
                .collect();
            let pattern = SparsePattern::new(n, &groups, false).unwrap();
            let mut rng = timesift_core::SeededRng::new(seed);
            let mut sparse = Reduced::sparse(pattern.clone());
            let mut dense = Reduced::dense(n);
            for c in 0..n {
                for k in pattern.col_ptr[c]..pattern.col_ptr[c + 1] {
                    let (r, v) = (pattern.row_idx[k], rng.uniform_range(-1.0, 1.0));
                    sparse.add(r, c, v);
                    dense.add(r, c, v);
                    if r != c {
                        dense.add(c, r, v);
                    }
                }
            }
            let x = DVector::from_fn(n, |_, _| rng.uniform_range(-2.0, 2.0));
            let want = sparse.mul_vec(&x);
            let mut scratch = Vec::new();
            for storage in [&sparse, &dense] {
                let mut got = DVector::zeros(n);
                // Twice: the kept scratch must not leak into the next product.
                for _ in 0..2 {
                    storage.mul_vec_into(x.as_slice(), got.as_mut_slice(), &mut scratch);
                }
                for i in 0..n {
                    prop_assert!((got[i] - want[i]).abs() < 1e-12 * (1.0 + want[i].abs()));
                }
            }
        }
    }

    /// A pattern built without the symbolic analysis gets it on request and then factorises.
    #[test]
    fn a_pattern_analysed_later_factorises() {
        let pattern = SparsePattern::new(3, &[vec![0, 1], vec![1, 2]], false).unwrap();
        let mut s = Reduced::sparse(pattern.clone());
        assert!(s.factor().is_none(), "no symbolic analysis yet");
        let mut s2 = Reduced::sparse(pattern.analysed().unwrap());
        for (r, c, v) in [
            (0, 0, 4.0),
            (1, 0, 1.0),
            (1, 1, 3.0),
            (2, 1, 1.0),
            (2, 2, 2.0),
        ] {
            s.add(r, c, v);
            s2.add(r, c, v);
        }
        let b = DVector::from_vec(vec![1.0, 2.0, 3.0]);
        let x = s2.solve(&b).unwrap();
        assert!((s2.mul_vec(&x) - b).norm() < 1e-12);
    }

    #[test]
    fn a_column_beyond_the_system_is_refused() {
        assert!(SparsePattern::new(4, &[vec![1, 4]], false).is_none());
    }
}
