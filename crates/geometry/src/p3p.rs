//! P3P by Lambda Twist (Persson & Nordberg, ECCV 2018): the three unknown depths λ satisfy three
//! quadratic forms `Λᵀ M_ij Λ = a_ij`; a combination of them with determinant zero is found from
//! one cubic, factors into two planes through the origin, and each plane leaves a quadratic in
//! the depth ratio. Depths are polished by Gauss–Newton and the pose follows from two difference
//! vectors and their cross product.

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use timesift_core::Pose;

use crate::GeometryError;
use crate::error::check_finite;
use crate::fundamental::adj_trace;
use crate::poly::{cubic_roots, quadratic_roots};

/// Squared distances and bearing cosines indexed by pairs.
struct Pairs {
    a: [[f64; 3]; 3],
    b: [[f64; 3]; 3],
}

impl Pairs {
    fn residuals(&self, l: &[f64; 3]) -> Vector3<f64> {
        let r = |i: usize, j: usize| {
            l[i] * l[i] + l[j] * l[j] - 2.0 * self.b[i][j] * l[i] * l[j] - self.a[i][j]
        };
        Vector3::new(r(0, 1), r(0, 2), r(1, 2))
    }

    /// Gauss–Newton on the three depth equations.
    fn refine(&self, l: &mut [f64; 3]) {
        for _ in 0..5 {
            let r = self.residuals(l);
            if r.amax() < 1e-15 * (self.a[0][1] + self.a[0][2] + self.a[1][2]) {
                return;
            }
            let d = |i: usize, j: usize| 2.0 * (l[i] - self.b[i][j] * l[j]);
            let j = Matrix3::new(
                d(0, 1),
                d(1, 0),
                0.0,
                d(0, 2),
                0.0,
                d(2, 0),
                0.0,
                d(1, 2),
                d(2, 1),
            );
            let Some(step) = j.lu().solve(&r) else { return };
            let next = [l[0] - step[0], l[1] - step[1], l[2] - step[2]];
            if next.iter().all(|v| v.is_finite() && *v > 0.0) {
                *l = next;
            } else {
                return;
            }
        }
    }

    /// Squared distances between the world points and cosines between the (unit) bearings.
    fn new(x: &[Vector3<f64>], y: &[Vector3<f64>]) -> Pairs {
        let mut p = Pairs {
            a: [[0.0; 3]; 3],
            b: [[0.0; 3]; 3],
        };
        for i in 0..3 {
            for j in 0..3 {
                p.a[i][j] = (x[i] - x[j]).norm_squared();
                p.b[i][j] = y[i].dot(&y[j]);
            }
        }
        p
    }

    /// `D1`, `D2` of the pencil `D1 + γ D2` of combinations of the quadratic forms `M_ij`, whose
    /// singular members (the cubic's roots γ) factor into two planes.
    fn pencil(&self) -> (Matrix3<f64>, Matrix3<f64>) {
        let (a12, a13, a23) = (self.a[0][1], self.a[0][2], self.a[1][2]);
        let (b12, b13, b23) = (self.b[0][1], self.b[0][2], self.b[1][2]);
        let m12 = Matrix3::new(1.0, -b12, 0.0, -b12, 1.0, 0.0, 0.0, 0.0, 0.0);
        let m13 = Matrix3::new(1.0, 0.0, -b13, 0.0, 0.0, 0.0, -b13, 0.0, 1.0);
        let m23 = Matrix3::new(0.0, 0.0, 0.0, 0.0, 1.0, -b23, 0.0, -b23, 1.0);
        let d1 = m12 * a23 - m23 * a12;
        let d2 = m13 * a23 - m23 * a13;
        (d1, d2)
    }

    /// The positive depth triples on a plane `plane · Λ = 0` through the origin, polished by
    /// Gauss–Newton: `λ_i = w_j λ_j + w_k λ_k` for the largest `|plane_i|`, which leaves a
    /// quadratic in the depth ratio `τ = λ_j / λ_k`.
    fn depths_on_plane(&self, plane: &Vector3<f64>) -> Vec<[f64; 3]> {
        let mut depths = Vec::new();
        let i = (0..3)
            .max_by(|&u, &v| plane[u].abs().total_cmp(&plane[v].abs()))
            .unwrap_or(0);
        let (j, k) = ((i + 1) % 3, (i + 2) % 3);
        if plane[i] == 0.0 {
            return depths;
        }
        let (wj, wk) = (-plane[j] / plane[i], -plane[k] / plane[i]);
        let (ajk, aij, bij, bjk) = (self.a[j][k], self.a[i][j], self.b[i][j], self.b[j][k]);
        let c2 = ajk * (wj * wj + 1.0 - 2.0 * bij * wj) - aij;
        let c1 = ajk * (2.0 * wj * wk - 2.0 * bij * wk) + 2.0 * aij * bjk;
        let c0 = ajk * wk * wk - aij;
        for tau in quadratic_roots(c2, c1, c0) {
            if !(tau > 0.0) {
                continue;
            }
            let denom = tau * tau - 2.0 * bjk * tau + 1.0;
            if !(denom > 0.0) {
                continue;
            }
            let lk = (ajk / denom).sqrt();
            let lj = tau * lk;
            let li = wj * lj + wk * lk;
            if !(li > 0.0) {
                continue;
            }
            let mut l = [0.0; 3];
            l[i] = li;
            l[j] = lj;
            l[k] = lk;
            self.refine(&mut l);
            depths.push(l);
        }
        depths
    }
}

/// What the poses of every root γ are built from: the unit bearings, the world points, the
/// inverse of the world points' difference frame and the pair data.
struct P3pFrame<'a> {
    y: &'a [Vector3<f64>],
    x: &'a [Vector3<f64>],
    xx_inv: Matrix3<f64>,
    pairs: &'a Pairs,
}

impl P3pFrame<'_> {
    /// Adds to `poses` those of one singular member `d0` of the pencil: it factors into the two
    /// planes `e1 ∓ s e2` (its eigenvectors of the two largest |eigenvalues|, of opposite signs),
    /// each giving depth triples; each pose is added unless finite duplicates exist already.
    fn add_poses(&self, d0: &Matrix3<f64>, poses: &mut Vec<Pose>) {
        let eig = d0.symmetric_eigen();
        let mut idx = [0usize, 1, 2];
        idx.sort_by(|&a, &b| {
            eig.eigenvalues[a]
                .abs()
                .total_cmp(&eig.eigenvalues[b].abs())
        });
        let (s1, s2) = (eig.eigenvalues[idx[2]], eig.eigenvalues[idx[1]]);
        if !(s1 * s2 < 0.0) {
            return;
        }
        let e1 = eig.eigenvectors.column(idx[2]).into_owned();
        let e2 = eig.eigenvectors.column(idx[1]).into_owned();
        let s = (-s2 / s1).sqrt();
        for sign in [1.0, -1.0] {
            let plane = e1 - e2 * (sign * s);
            for l in self.pairs.depths_on_plane(&plane) {
                let pose = self.pose_from_depths(&l);
                if pose
                    .rotation
                    .coords
                    .iter()
                    .chain(pose.translation.iter())
                    .all(|v| v.is_finite())
                    && !poses.iter().any(|q| {
                        q.rotation.angle_to(&pose.rotation) < 1e-9
                            && (q.translation - pose.translation).norm()
                                < 1e-9 * (1.0 + pose.translation.norm())
                    })
                {
                    poses.push(pose);
                }
            }
        }
    }

    /// The pose that puts the world points at depths `l` along the bearings: the rotation from two
    /// difference vectors and their cross product, then the translation.
    fn pose_from_depths(&self, l: &[f64; 3]) -> Pose {
        let (y, x) = (self.y, self.x);
        let v1 = y[0] * l[0] - y[1] * l[1];
        let v2 = y[0] * l[0] - y[2] * l[2];
        let yy = Matrix3::from_columns(&[v1, v2, v1.cross(&v2)]);
        let r = nearest_rotation(&(yy * self.xx_inv));
        let t = y[0] * l[0] - r * x[0];
        Pose::new(UnitQuaternion::from_rotation_matrix(&r), t)
    }
}

/// Every pose `cam_from_world` that maps the three world points onto the three bearings (up to
/// four). `bearings` are viewing directions in the camera frame (any positive scale).
pub fn p3p(bearings: &[Vector3<f64>], world: &[Vector3<f64>]) -> Result<Vec<Pose>, GeometryError> {
    let solver = "P3P";
    if bearings.len() < 3 || world.len() < 3 {
        return Err(GeometryError::NotEnoughData {
            solver,
            needed: 3,
            got: bearings.len().min(world.len()),
        });
    }
    check_finite(
        solver,
        bearings[..3]
            .iter()
            .chain(&world[..3])
            .flat_map(|v| v.iter()),
    )?;
    let y: Vec<Vector3<f64>> = bearings[..3].iter().map(|v| v.normalize()).collect();
    let x = &world[..3];
    let d12 = x[0] - x[1];
    let d13 = x[0] - x[2];
    let normal = d12.cross(&d13);
    if !(normal.norm_squared() > 1e-12 * d12.norm_squared() * d13.norm_squared()) {
        return Err(GeometryError::Degenerate {
            solver,
            reason: "the three world points are collinear",
        });
    }
    if y.iter().any(|v| !v.iter().all(|c| c.is_finite())) {
        return Err(GeometryError::NonFinite { solver });
    }
    let pairs = Pairs::new(x, &y);
    let (d1, d2) = pairs.pencil();
    let gammas = cubic_roots(
        d2.determinant(),
        adj_trace(&d2, &d1),
        adj_trace(&d1, &d2),
        d1.determinant(),
    );

    let xx = Matrix3::from_columns(&[d12, d13, normal]);
    let Some(xx_inv) = xx.try_inverse() else {
        return Err(GeometryError::Degenerate {
            solver,
            reason: "the three world points are collinear",
        });
    };
    let frame = P3pFrame {
        y: &y,
        x,
        xx_inv,
        pairs: &pairs,
    };
    let mut poses: Vec<Pose> = Vec::new();
    for gamma in gammas {
        frame.add_poses(&(d1 + d2 * gamma), &mut poses);
        if !poses.is_empty() {
            break;
        }
    }
    Ok(poses)
}

/// The rotation closest (Frobenius) to a matrix.
pub(crate) fn nearest_rotation(m: &Matrix3<f64>) -> Rotation3<f64> {
    let svd = m.svd(true, true);
    match (svd.u, svd.v_t) {
        (Some(u), Some(vt)) => {
            let mut d = Matrix3::identity();
            if (u * vt).determinant() < 0.0 {
                d[(2, 2)] = -1.0;
            }
            Rotation3::from_matrix_unchecked(u * d * vt)
        }
        _ => Rotation3::identity(),
    }
}
