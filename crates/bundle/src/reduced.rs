//! Storage of the reduced camera system `S`: dense for small problems, or sparse (lower triangle,
//! compressed columns) with a symbolic Cholesky analysis computed once per solve and a numeric
//! factorisation per trial step (faer).

use std::sync::Arc;

use faer::Side;
use faer::sparse::linalg::solvers::{Llt, SymbolicLlt};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use nalgebra::{DMatrix, DVector};

/// The fixed sparsity pattern of `S` (lower triangle) and its symbolic factorisation.
pub(crate) struct SparsePattern {
    n: usize,
    pub(crate) col_ptr: Vec<usize>,
    pub(crate) row_idx: Vec<usize>,
    /// `None` for patterns used only for products (the iterative solver).
    symbolic: Option<SymbolicLlt<usize>>,
}

impl SparsePattern {
    /// Builds the pattern from the sets of camera-side columns that interact (each set couples all
    /// its columns); the diagonal is always present.
    /// `factorise`: run the symbolic Cholesky analysis (not needed by the iterative solver).
    pub(crate) fn new(n: usize, groups: &[Vec<usize>], factorise: bool) -> Option<Arc<Self>> {
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
        let mut col_ptr = Vec::with_capacity(n + 1);
        let mut row_idx = Vec::new();
        col_ptr.push(0);
        for r in rows.iter_mut() {
            r.sort_unstable();
            r.dedup();
            row_idx.extend_from_slice(r);
            col_ptr.push(row_idx.len());
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
        Some(Arc::new(SparsePattern {
            n,
            col_ptr,
            row_idx,
            symbolic,
        }))
    }

    /// Stored entries (lower triangle with the diagonal).
    pub(crate) fn nnz_lower(&self) -> usize {
        self.row_idx.len()
    }

    fn slot(&self, row: usize, col: usize) -> Option<usize> {
        let (r, c) = if row >= col { (row, col) } else { (col, row) };
        let start = self.col_ptr[c];
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

    pub(crate) fn diagonal(&self, i: usize) -> f64 {
        match self {
            Reduced::Dense(m) => m[(i, i)],
            Reduced::Sparse { pattern, values } => pattern.slot(i, i).map_or(0.0, |k| values[k]),
        }
    }

    /// Factors `S` by Cholesky and solves `S X = B` in place for the columns of `rhs`; `None` when
    /// `S` is not positive definite.
    fn solve_in_place(&self, rhs: &mut faer::Mat<f64>) -> Option<()> {
        use faer::prelude::Solve;
        match self {
            Reduced::Dense(m) => {
                let n = m.nrows();
                let fm = faer::Mat::<f64>::from_fn(n, n, |i, j| m[(i, j)]);
                fm.llt(Side::Lower).ok()?.solve_in_place(rhs.as_mut());
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
                Llt::try_new_with_symbolic(pattern.symbolic.clone()?, mat, Side::Lower)
                    .ok()?
                    .solve_in_place(rhs.as_mut());
            }
        }
        Some(())
    }

    /// Solves `S x = b` by Cholesky; `None` when `S` is not positive definite.
    pub(crate) fn solve(&self, b: &DVector<f64>) -> Option<DVector<f64>> {
        let n = b.len();
        let mut x = faer::Mat::<f64>::from_fn(n, 1, |i, _| b[i]);
        self.solve_in_place(&mut x)?;
        let out = DVector::from_fn(n, |i, _| x[(i, 0)]);
        out.iter().all(|v| v.is_finite()).then_some(out)
    }

    /// Diagonal blocks `(start, len)` of `S⁻¹`, from one Cholesky factorisation and solves against
    /// the identity columns of the blocks (in batches, so memory stays at n × 256); `None` when
    /// `S` is not positive definite.
    /// Columns `columns` of the inverse (n × columns.len()), or `None` when a solve fails.
    pub(crate) fn inverse_columns(&self, columns: &[usize]) -> Option<faer::Mat<f64>> {
        let n = match self {
            Reduced::Dense(m) => m.nrows(),
            Reduced::Sparse { pattern, .. } => pattern.n,
        };
        let mut rhs = faer::Mat::<f64>::zeros(n, columns.len());
        for (k, &c) in columns.iter().enumerate() {
            rhs[(c, k)] = 1.0;
        }
        self.solve_in_place(&mut rhs)?;
        (0..columns.len())
            .all(|k| (0..n).all(|i| rhs[(i, k)].is_finite()))
            .then_some(rhs)
    }

    pub(crate) fn inverse_diagonal_blocks(
        &self,
        blocks: &[(usize, usize)],
    ) -> Option<Vec<DMatrix<f64>>> {
        let n = match self {
            Reduced::Dense(m) => m.nrows(),
            Reduced::Sparse { pattern, .. } => pattern.n,
        };
        // (column of S, block, column within the block)
        let columns: Vec<(usize, usize, usize)> = blocks
            .iter()
            .enumerate()
            .flat_map(|(b, &(s, l))| (0..l).map(move |j| (s + j, b, j)))
            .collect();
        let mut out: Vec<DMatrix<f64>> =
            blocks.iter().map(|&(_, l)| DMatrix::zeros(l, l)).collect();
        // Dense: one factorisation for all columns; sparse: one per batch of 256 columns (cheap
        // next to the solves, and keeps the borrow simple).
        let batch = if matches!(self, Reduced::Dense(_)) {
            columns.len().max(1)
        } else {
            256
        };
        for chunk in columns.chunks(batch) {
            let mut rhs = faer::Mat::<f64>::zeros(n, chunk.len());
            for (k, &(c, _, _)) in chunk.iter().enumerate() {
                rhs[(c, k)] = 1.0;
            }
            self.solve_in_place(&mut rhs)?;
            for (k, &(_, b, j)) in chunk.iter().enumerate() {
                let (start, len) = blocks[b];
                for i in 0..len {
                    out[b][(i, j)] = rhs[(start + i, k)];
                }
            }
        }
        if !out.iter().all(|m| m.iter().all(|v| v.is_finite())) {
            return None;
        }
        Some(out)
    }
}
