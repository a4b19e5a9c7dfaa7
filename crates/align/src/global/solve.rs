//! Preconditioned conjugate gradients for the two sparse, symmetric positive-definite systems of
//! the global mapper: a weighted graph Laplacian (rotation averaging, the same for each of the
//! three axes) and a 3 × 3 block system (positions). Both are graph-shaped with a few tens of
//! edges per node: CG with a (block-)Jacobi preconditioner solves them without forming or
//! factorising a matrix, each iteration linear in the edges (iterations grow with the graph's
//! diameter, some hundreds for a block of hundreds of images).

use nalgebra::{Matrix3, Vector3};

/// Relative residual at which CG stops (the systems are linearisations, solved again in the
/// next round of reweighting).
const TOLERANCE: f64 = 1e-10;

/// A symmetric operator on vectors of 3-vectors, with the inverse of its 3 × 3 diagonal blocks.
pub(crate) trait BlockOperator {
    /// Unknowns (3-vectors).
    fn len(&self) -> usize;
    /// `y = A x`.
    fn apply(&self, x: &[Vector3<f64>], y: &mut [Vector3<f64>]);
    /// The diagonal blocks (their inverses precondition).
    fn diagonal(&self) -> Vec<Matrix3<f64>>;
}

fn dot(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x.dot(y)).sum()
}

/// Solves `A x = b` from `x = 0`. Returns the solution and the iterations taken; `None` when the
/// operator is not positive definite along some search direction (a gauge left free, an
/// unknown nothing observes) or the residual does not fall below [`TOLERANCE`] in `max_iterations`.
pub(crate) fn conjugate_gradients(
    a: &impl BlockOperator,
    b: &[Vector3<f64>],
    max_iterations: usize,
) -> Option<(Vec<Vector3<f64>>, usize)> {
    let n = a.len();
    let preconditioner: Vec<Matrix3<f64>> = a
        .diagonal()
        .iter()
        .map(|block| block.try_inverse().unwrap_or_else(Matrix3::identity))
        .collect();
    let mut x = vec![Vector3::zeros(); n];
    let mut r = b.to_vec();
    let norm_b = dot(b, b).sqrt();
    if norm_b == 0.0 {
        return Some((x, 0));
    }
    let mut z: Vec<Vector3<f64>> = r.iter().zip(&preconditioner).map(|(r, m)| m * r).collect();
    let mut p = z.clone();
    let mut ap = vec![Vector3::zeros(); n];
    let mut rz = dot(&r, &z);
    for iteration in 0..max_iterations {
        a.apply(&p, &mut ap);
        let curvature = dot(&p, &ap);
        if !(curvature > 0.0) {
            return None;
        }
        let alpha = rz / curvature;
        for k in 0..n {
            x[k] += alpha * p[k];
            r[k] -= alpha * ap[k];
        }
        if dot(&r, &r).sqrt() <= TOLERANCE * norm_b {
            return Some((x, iteration + 1));
        }
        for k in 0..n {
            z[k] = preconditioner[k] * r[k];
        }
        let rz_next = dot(&r, &z);
        let beta = rz_next / rz;
        rz = rz_next;
        for k in 0..n {
            p[k] = z[k] + beta * p[k];
        }
    }
    None
}

/// The weighted graph Laplacian `L ⊗ I₃` of edges (i, j, w), plus `anchor` on the diagonal of
/// one node (the gauge).
pub(crate) struct Laplacian<'e> {
    pub nodes: usize,
    pub edges: &'e [(usize, usize, f64)],
    /// Per node: the sum of its edges' weights, and the anchor's weight on its node.
    pub degree: Vec<f64>,
}

impl<'e> Laplacian<'e> {
    pub fn new(nodes: usize, edges: &'e [(usize, usize, f64)], anchor: (usize, f64)) -> Self {
        let mut degree = vec![0.0; nodes];
        for &(i, j, w) in edges {
            degree[i] += w;
            degree[j] += w;
        }
        degree[anchor.0] += anchor.1;
        Laplacian {
            nodes,
            edges,
            degree,
        }
    }
}

impl BlockOperator for Laplacian<'_> {
    fn len(&self) -> usize {
        self.nodes
    }
    fn apply(&self, x: &[Vector3<f64>], y: &mut [Vector3<f64>]) {
        for (k, y) in y.iter_mut().enumerate() {
            *y = x[k] * self.degree[k];
        }
        for &(i, j, w) in self.edges {
            y[i] -= w * x[j];
            y[j] -= w * x[i];
        }
    }
    fn diagonal(&self) -> Vec<Matrix3<f64>> {
        self.degree
            .iter()
            .map(|d| Matrix3::identity() * *d)
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// On a random connected graph (a path plus random chords) with one node anchored, CG
        /// solves the Laplacian system to the tolerance: L x reproduces b.
        #[test]
        fn cg_solves_an_anchored_laplacian(
            n in 2usize..60,
            chords in proptest::collection::vec((0usize..60, 0usize..60, 0.1f64..10.0), 0..120),
            rhs in proptest::collection::vec(-5.0f64..5.0, 180),
        ) {
            let mut edges: Vec<(usize, usize, f64)> = (1..n).map(|k| (k - 1, k, 1.0)).collect();
            edges.extend(chords.into_iter().filter(|(i, j, _)| i < &n && j < &n && i != j));
            let laplacian = Laplacian::new(n, &edges, (0, 1.0));
            let b: Vec<Vector3<f64>> =
                (0..n).map(|k| Vector3::new(rhs[3 * k], rhs[3 * k + 1], rhs[3 * k + 2])).collect();
            let (x, _) = conjugate_gradients(&laplacian, &b, 10 * n + 100).unwrap();
            let mut lx = vec![Vector3::zeros(); n];
            laplacian.apply(&x, &mut lx);
            for (got, want) in lx.iter().zip(&b) {
                prop_assert!((got - want).norm() < 1e-8 * (1.0 + want.norm()));
            }
        }
    }

    /// Without the anchor the Laplacian is singular along the constant vector: with a right-hand
    /// side outside its range CG finds no solution and says so.
    #[test]
    fn an_unanchored_laplacian_with_an_inconsistent_right_hand_side_fails() {
        let edges = [(0, 1, 1.0), (1, 2, 1.0)];
        let laplacian = Laplacian::new(3, &edges, (0, 0.0));
        let b = vec![Vector3::new(1.0, 0.0, 0.0); 3];
        assert!(conjugate_gradients(&laplacian, &b, 100).is_none());
    }
}
