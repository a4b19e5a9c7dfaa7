//! The essential matrix: Stewénius' five-point solver (Gröbner basis / action matrix), a linear
//! eight-point fit for many points, decomposition into a relative pose with the cheirality test,
//! and the RANSAC estimator.
//!
//! Convention: `x2ᵀ E x1 = 0` with `E = [t]× R` for `cam2_from_cam1 = (R, t)`; `x1`, `x2` are
//! viewing rays (any positive scale; normalised image coordinates with z = 1 are typical).

use nalgebra::{Matrix3, SMatrix, SVector, UnitQuaternion, Vector2, Vector3};
use timesift_core::Pose;

use crate::GeometryError;
use crate::error::{check_finite, check_pairs};
use crate::normalize::{normalize_points, null_matrix};
use crate::ransac::Estimator;
use crate::triangulation::triangulate_two_view_midpoint;

/// Exponents (x, y, z) of the 20 monomials of degree ≤ 3: the ten cubic ones first, then the
/// action-matrix basis x², xy, xz, y², yz, z², x, y, z, 1.
const MONOMIALS: [(usize, usize, usize); 20] = [
    (3, 0, 0),
    (2, 1, 0),
    (2, 0, 1),
    (1, 2, 0),
    (1, 1, 1),
    (1, 0, 2),
    (0, 3, 0),
    (0, 2, 1),
    (0, 1, 2),
    (0, 0, 3),
    (2, 0, 0),
    (1, 1, 0),
    (1, 0, 1),
    (0, 2, 0),
    (0, 1, 1),
    (0, 0, 2),
    (1, 0, 0),
    (0, 1, 0),
    (0, 0, 1),
    (0, 0, 0),
];

/// A polynomial of degree ≤ 3 in (x, y, z), coefficients in [`MONOMIALS`] order.
type Poly = [f64; 20];

fn monomial_index(e: (usize, usize, usize)) -> usize {
    MONOMIALS.iter().position(|m| *m == e).unwrap_or(usize::MAX)
}

/// Index table: `INDEX[a][b][c]` of x^a y^b z^c (a + b + c ≤ 3).
fn index_table() -> [[[usize; 4]; 4]; 4] {
    let mut t = [[[usize::MAX; 4]; 4]; 4];
    for (i, &(a, b, c)) in MONOMIALS.iter().enumerate() {
        t[a][b][c] = i;
    }
    t
}

fn poly_mul(p: &Poly, q: &Poly, table: &[[[usize; 4]; 4]; 4]) -> Poly {
    let mut r = [0.0; 20];
    for (i, &pi) in p.iter().enumerate() {
        if pi == 0.0 {
            continue;
        }
        let (a1, b1, c1) = MONOMIALS[i];
        for (j, &qj) in q.iter().enumerate() {
            if qj == 0.0 {
                continue;
            }
            let (a2, b2, c2) = MONOMIALS[j];
            let (a, b, c) = (a1 + a2, b1 + b2, c1 + c2);
            if a + b + c <= 3 {
                r[table[a][b][c]] += pi * qj;
            }
        }
    }
    r
}

fn poly_add(p: &Poly, q: &Poly, s: f64) -> Poly {
    let mut r = *p;
    for (a, b) in r.iter_mut().zip(q) {
        *a += s * b;
    }
    r
}

/// Five-point solver: every real essential matrix consistent with five correspondences (up to
/// ten). Returns an empty list for degenerate samples.
pub fn five_point(
    x1: &[Vector3<f64>],
    x2: &[Vector3<f64>],
) -> Result<Vec<Matrix3<f64>>, GeometryError> {
    check_pairs("five-point", x1.len(), x2.len(), 5)?;
    check_finite("five-point", x1.iter().chain(x2).flat_map(|v| v.iter()))?;
    if x1[..5].iter().chain(&x2[..5]).any(|v| !(v.norm() > 0.0)) {
        return Err(GeometryError::Degenerate {
            solver: "five-point",
            reason: "a ray has zero length",
        });
    }
    let Some(basis) = epipolar_null_space(x1, x2) else {
        return Ok(Vec::new());
    };
    let table = index_table();
    let constraints = essential_constraints(&basis, &table);
    let Some(a) = eliminate_cubics(&constraints) else {
        return Ok(Vec::new());
    };
    let action = action_matrix(&a, &table);
    // `complex_eigenvalues()` iterates without bound and can hang on rare samples: cap the Schur
    // iterations and treat non-convergence as a degenerate sample.
    let Some(schur) = nalgebra::linalg::Schur::try_new(action, f64::EPSILON, 1000) else {
        return Ok(Vec::new());
    };
    let mut solutions = Vec::new();
    for lambda in schur.complex_eigenvalues().iter() {
        if lambda.im.abs() > 1e-8 * (1.0 + lambda.re.abs()) {
            continue;
        }
        let Some(m) = essential_of_eigenvalue(&action, lambda.re, &basis) else {
            continue;
        };
        let norm = m.norm();
        if norm > 0.0 && m.iter().all(|v| v.is_finite()) {
            let m = m / norm;
            if !solutions
                .iter()
                .any(|s: &Matrix3<f64>| (s - m).norm() < 1e-9 || (s + m).norm() < 1e-9)
            {
                solutions.push(m);
            }
        }
    }
    Ok(solutions)
}

/// Basis `X, Y, Z, W` (row-major 3 × 3 each) of the null space of the 5 × 9 epipolar constraint
/// matrix, from the SVD of its zero-padded square; `None` when the SVD fails or the constraints
/// are not of rank 5 (a degenerate sample).
fn epipolar_null_space(x1: &[Vector3<f64>], x2: &[Vector3<f64>]) -> Option<Vec<[f64; 9]>> {
    let mut q = SMatrix::<f64, 9, 9>::zeros();
    for k in 0..5 {
        let (a, b) = (x1[k].normalize(), x2[k].normalize());
        for i in 0..3 {
            for j in 0..3 {
                q[(k, 3 * i + j)] = b[i] * a[j];
            }
        }
    }
    // Capped iterations: nalgebra's plain `svd()` iterates without bound.
    let svd = q.try_svd(false, true, f64::EPSILON, 1000)?;
    let v_t = svd.v_t?;
    let mut order: Vec<usize> = (0..9).collect();
    order.sort_by(|&a, &b| svd.singular_values[a].total_cmp(&svd.singular_values[b]));
    // Rank 5 is required: the sixth smallest singular value must not vanish.
    let largest = svd.singular_values[order[8]];
    if !(svd.singular_values[order[4]] > 1e-12 * largest) {
        return None;
    }
    Some(
        order[..4]
            .iter()
            .map(|&r| {
                let mut m = [0.0; 9];
                for (c, v) in m.iter_mut().enumerate() {
                    *v = v_t[(r, c)];
                }
                m
            })
            .collect(),
    )
}

/// The ten cubic constraints on `E = x X + y Y + z Z + W`: `det(E) = 0` and the nine entries of
/// `2 E Eᵀ E − tr(E Eᵀ) E = 0`, in that order.
fn essential_constraints(basis: &[[f64; 9]], table: &[[[usize; 4]; 4]; 4]) -> Vec<Poly> {
    // E = x X + y Y + z Z + W, each entry a linear polynomial.
    let (ix, iy, iz, i1) = (
        monomial_index((1, 0, 0)),
        monomial_index((0, 1, 0)),
        monomial_index((0, 0, 1)),
        monomial_index((0, 0, 0)),
    );
    let mut e: [[Poly; 3]; 3] = [[[0.0; 20]; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            let k = 3 * i + j;
            e[i][j][ix] = basis[0][k];
            e[i][j][iy] = basis[1][k];
            e[i][j][iz] = basis[2][k];
            e[i][j][i1] = basis[3][k];
        }
    }
    let mul = |p: &Poly, q: &Poly| poly_mul(p, q, table);

    let mut constraints: Vec<Poly> = Vec::with_capacity(10);
    // det(E) = 0.
    let minor = |a: usize, b: usize, c: usize, d: usize| {
        poly_add(&mul(&e[1][a], &e[2][b]), &mul(&e[1][c], &e[2][d]), -1.0)
    };
    let det = poly_add(
        &poly_add(
            &mul(&e[0][0], &minor(1, 2, 2, 1)),
            &mul(&e[0][1], &minor(0, 2, 2, 0)),
            -1.0,
        ),
        &mul(&e[0][2], &minor(0, 1, 1, 0)),
        1.0,
    );
    constraints.push(det);
    // 2 E Eᵀ E − tr(E Eᵀ) E = 0.
    let mut eet: [[Poly; 3]; 3] = [[[0.0; 20]; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            let mut s = [0.0; 20];
            for k in 0..3 {
                s = poly_add(&s, &mul(&e[i][k], &e[j][k]), 1.0);
            }
            eet[i][j] = s;
        }
    }
    let trace = poly_add(&poly_add(&eet[0][0], &eet[1][1], 1.0), &eet[2][2], 1.0);
    for i in 0..3 {
        for j in 0..3 {
            let mut s = [0.0; 20];
            for k in 0..3 {
                s = poly_add(&s, &mul(&eet[i][k], &e[k][j]), 2.0);
            }
            constraints.push(poly_add(&s, &mul(&trace, &e[i][j]), -1.0));
        }
    }
    constraints
}

/// Gauss–Jordan elimination of the cubic monomials (the first ten columns) from the constraints'
/// coefficient rows; `None` when a pivot vanishes (a degenerate sample).
fn eliminate_cubics(constraints: &[Poly]) -> Option<SMatrix<f64, 10, 20>> {
    let mut a = SMatrix::<f64, 10, 20>::zeros();
    for (r, c) in constraints.iter().enumerate() {
        for k in 0..20 {
            a[(r, k)] = c[k];
        }
    }
    for col in 0..10 {
        let pivot = (col..10)
            .max_by(|&p, &q| a[(p, col)].abs().total_cmp(&a[(q, col)].abs()))
            .unwrap_or(col);
        let scale = a.row(pivot).amax();
        if !(a[(pivot, col)].abs() > 1e-12 * scale) {
            return None;
        }
        a.swap_rows(col, pivot);
        let p = a[(col, col)];
        for k in 0..20 {
            a[(col, k)] /= p;
        }
        for r in 0..10 {
            if r != col {
                let f = a[(r, col)];
                if f != 0.0 {
                    for k in 0..20 {
                        a[(r, k)] -= f * a[(col, k)];
                    }
                }
            }
        }
    }
    Some(a)
}

/// Action matrix of multiplication by x on the basis (x², xy, xz, y², yz, z², x, y, z, 1), from
/// the eliminated constraints.
fn action_matrix(a: &SMatrix<f64, 10, 20>, table: &[[[usize; 4]; 4]; 4]) -> SMatrix<f64, 10, 10> {
    let mut action = SMatrix::<f64, 10, 10>::zeros();
    for k in 0..10 {
        let (p, q, r) = MONOMIALS[10 + k];
        let target = table[p + 1][q][r];
        if target < 10 {
            for c in 0..10 {
                action[(k, c)] = -a[(target, 10 + c)];
            }
        } else {
            action[(k, target - 10)] = 1.0;
        }
    }
    action
}

/// The essential matrix (not normalised) of a real eigenvalue of the action matrix: (x, y, z)
/// read from its eigenvector (the right singular vector of the smallest singular value of the
/// shifted matrix); `None` when the SVD fails or the vector's constant term vanishes.
fn essential_of_eigenvalue(
    action: &SMatrix<f64, 10, 10>,
    lambda: f64,
    basis: &[[f64; 9]],
) -> Option<Matrix3<f64>> {
    let shifted = action - SMatrix::<f64, 10, 10>::identity() * lambda;
    let svd = shifted.svd(false, true);
    let vt = svd.v_t?;
    let (min_idx, _) =
        svd.singular_values
            .iter()
            .enumerate()
            .fold(
                (0, f64::INFINITY),
                |acc, (i, &s)| if s < acc.1 { (i, s) } else { acc },
            );
    let v: SVector<f64, 10> = vt.row(min_idx).transpose();
    if v[9].abs() < 1e-12 * v.amax() {
        return None;
    }
    let (x, y, z) = (v[6] / v[9], v[7] / v[9], v[8] / v[9]);
    let mut m = Matrix3::zeros();
    for i in 0..3 {
        for j in 0..3 {
            let k = 3 * i + j;
            m[(i, j)] = x * basis[0][k] + y * basis[1][k] + z * basis[2][k] + basis[3][k];
        }
    }
    Some(m)
}

/// Linear least-squares essential matrix from eight or more correspondences (optionally weighted),
/// projected onto the essential manifold (singular values 1, 1, 0).
pub fn eight_point_essential(
    x1: &[Vector3<f64>],
    x2: &[Vector3<f64>],
    weights: Option<&[f64]>,
) -> Result<Matrix3<f64>, GeometryError> {
    check_pairs("eight-point essential", x1.len(), x2.len(), 8)?;
    check_finite(
        "eight-point essential",
        x1.iter().chain(x2).flat_map(|v| v.iter()),
    )?;
    if let Some(w) = weights {
        check_pairs("eight-point essential", x1.len(), w.len(), 8)?;
    }
    // Hartley normalisation of the z = 1 coordinates: without it the constant third coordinate
    // dominates and the linear fit is badly conditioned.
    let plane = |x: &[Vector3<f64>]| -> Vec<Vector2<f64>> {
        x.iter()
            .map(|v| Vector2::new(v.x / v.z, v.y / v.z))
            .collect()
    };
    let (p1, p2) = (plane(x1), plane(x2));
    check_finite(
        "eight-point essential",
        p1.iter().chain(&p2).flat_map(|v| v.iter()),
    )?;
    let (Some((t1, n1)), Some((t2, n2))) = (normalize_points(&p1), normalize_points(&p2)) else {
        return Err(GeometryError::Degenerate {
            solver: "eight-point essential",
            reason: "all points coincide",
        });
    };
    let mut ata = SMatrix::<f64, 9, 9>::zeros();
    for k in 0..n1.len() {
        let (a, b) = (n1[k].push(1.0), n2[k].push(1.0));
        let w = weights.map_or(1.0, |w| w[k]);
        let mut row = SVector::<f64, 9>::zeros();
        for i in 0..3 {
            for j in 0..3 {
                row[3 * i + j] = b[i] * a[j];
            }
        }
        ata += row * row.transpose() * w;
    }
    let e = null_matrix(
        &ata,
        1e-14,
        "eight-point essential",
        "the correspondences do not determine E (critical configuration)",
    )?;
    let m = t2.transpose() * e * t1;
    Ok(project_to_essential(&m))
}

/// The closest essential matrix (Frobenius) with unit non-zero singular values.
pub fn project_to_essential(m: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = m.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return *m;
    };
    let mut s = svd.singular_values;
    // nalgebra sorts singular values in decreasing order.
    s[0] = 1.0;
    s[1] = 1.0;
    s[2] = 0.0;
    u * Matrix3::from_diagonal(&s) * vt
}

/// Sampson distance squared of a correspondence for `x2ᵀ F x1 = 0` (E or F), in the units of the
/// points' first two coordinates (rays are scaled to z = 1 first).
pub fn sampson_distance_sq(f: &Matrix3<f64>, x1: &Vector3<f64>, x2: &Vector3<f64>) -> f64 {
    let a = x1 / x1.z;
    let b = x2 / x2.z;
    let fx1 = f * a;
    let ftx2 = f.transpose() * b;
    let num = b.dot(&fx1);
    let den = fx1.x * fx1.x + fx1.y * fx1.y + ftx2.x * ftx2.x + ftx2.y * ftx2.y;
    if den <= 0.0 {
        f64::INFINITY
    } else {
        num * num / den
    }
}

/// The four `(R, t)` decompositions of an essential matrix (t of unit length).
pub fn decompose_essential(e: &Matrix3<f64>) -> [Pose; 4] {
    let svd = e.svd(true, true);
    let (mut u, mut vt) = match (svd.u, svd.v_t) {
        (Some(u), Some(vt)) => (u, vt),
        _ => (Matrix3::identity(), Matrix3::identity()),
    };
    if u.determinant() < 0.0 {
        u = -u;
    }
    if vt.determinant() < 0.0 {
        vt = -vt;
    }
    let w = Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    let r1 = u * w * vt;
    let r2 = u * w.transpose() * vt;
    let t = u.column(2).into_owned();
    let pose = |r: Matrix3<f64>, t: Vector3<f64>| {
        Pose::new(
            UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix_unchecked(r)),
            t,
        )
    };
    [pose(r1, t), pose(r1, -t), pose(r2, t), pose(r2, -t)]
}

/// The relative pose `cam2_from_cam1` (unit translation) of an essential matrix: the
/// decomposition that puts the most of the given correspondences in front of both cameras.
/// Returns the pose and the number of correspondences passing the cheirality test.
pub fn relative_pose_from_essential(
    e: &Matrix3<f64>,
    x1: &[Vector3<f64>],
    x2: &[Vector3<f64>],
) -> Result<(Pose, usize), GeometryError> {
    check_pairs("relative pose", x1.len(), x2.len(), 1)?;
    let mut best: Option<(Pose, usize)> = None;
    for pose in decompose_essential(e) {
        let c1 = Pose::identity();
        let count = x1
            .iter()
            .zip(x2)
            .filter(|(a, b)| {
                triangulate_two_view_midpoint(&c1, a, &pose, b)
                    .is_ok_and(|p| p.z > 0.0 && pose.transform_point(&p).z > 0.0)
            })
            .count();
        if best.as_ref().is_none_or(|b| count > b.1) {
            best = Some((pose, count));
        }
    }
    match best {
        Some((pose, count)) if count > 0 => Ok((pose, count)),
        _ => Err(GeometryError::NoSolution {
            solver: "relative pose",
            reason: "no decomposition puts points in front of both cameras",
        }),
    }
}

/// Sampson residual (signed) of a correspondence for E and its derivatives with respect to the
/// local relative-pose update of [`refine_relative_pose`] (three rotation, two translation).
fn sampson_with_jacobian(
    e: &Matrix3<f64>,
    d_e: &[Matrix3<f64>; 5],
    a: &Vector3<f64>,
    b: &Vector3<f64>,
) -> (f64, [f64; 5]) {
    let ea = e * a;
    let etb = e.transpose() * b;
    let n = b.dot(&ea);
    let d = ea.x * ea.x + ea.y * ea.y + etb.x * etb.x + etb.y * etb.y;
    let sd = d.sqrt();
    let mut j = [0.0; 5];
    for k in 0..5 {
        let dea = d_e[k] * a;
        let detb = d_e[k].transpose() * b;
        let dn = b.dot(&dea);
        let dd = 2.0 * (ea.x * dea.x + ea.y * dea.y + etb.x * detb.x + etb.y * detb.y);
        j[k] = dn / sd - n * dd / (2.0 * d * sd);
    }
    (n / sd, j)
}

/// An orthonormal pair spanning the plane perpendicular to a unit vector.
fn tangent_basis(t: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let helper = if t.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let b1 = t.cross(&helper).normalize();
    (b1, t.cross(&b1))
}

/// Applies the local update `(δω, δ1, δ2)`: `R ← exp([δω]×) R`, `t ← normalise(t + δ1 b1 + δ2 b2)`.
pub fn retract_relative_pose(pose: &Pose, delta: &[f64; 5]) -> Pose {
    let t = pose.translation.normalize();
    let (b1, b2) = tangent_basis(&t);
    Pose::new(
        UnitQuaternion::from_scaled_axis(Vector3::new(delta[0], delta[1], delta[2]))
            * pose.rotation,
        (t + b1 * delta[3] + b2 * delta[4]).normalize(),
    )
}

/// Sampson residuals of all correspondences for a relative pose and their Jacobian with respect
/// to the update of [`retract_relative_pose`] (one row per correspondence).
pub fn relative_pose_residuals(
    pose: &Pose,
    x1: &[Vector3<f64>],
    x2: &[Vector3<f64>],
) -> Vec<(f64, [f64; 5])> {
    let t = pose.translation.normalize();
    let r = pose.rotation_matrix();
    let (b1, b2) = tangent_basis(&t);
    let tx = t.cross_matrix();
    let e = tx * r;
    let d_e = [
        tx * Vector3::x().cross_matrix() * r,
        tx * Vector3::y().cross_matrix() * r,
        tx * Vector3::z().cross_matrix() * r,
        b1.cross_matrix() * r,
        b2.cross_matrix() * r,
    ];
    x1.iter()
        .zip(x2)
        .map(|(a, b)| sampson_with_jacobian(&e, &d_e, &(a / a.z), &(b / b.z)))
        .collect()
}

/// Refines a relative pose (unit translation) by Levenberg–Marquardt on the (weighted) squared
/// Sampson errors of the correspondences, the first-order geometric error of both images.
pub fn refine_relative_pose(
    start: &Pose,
    x1: &[Vector3<f64>],
    x2: &[Vector3<f64>],
    weights: Option<&[f64]>,
) -> Result<Pose, GeometryError> {
    check_pairs("relative pose refinement", x1.len(), x2.len(), 5)?;
    let cost = |rows: &[(f64, [f64; 5])]| -> f64 {
        rows.iter()
            .enumerate()
            .map(|(i, (r, _))| weights.map_or(1.0, |w| w[i]) * r * r)
            .sum()
    };
    if !(start.translation.norm() > 0.0) {
        return Err(GeometryError::Degenerate {
            solver: "relative pose refinement",
            reason: "zero translation (no baseline)",
        });
    }
    if let Some(w) = weights {
        check_pairs("relative pose refinement", x1.len(), w.len(), 5)?;
    }
    let mut pose = Pose::new(start.rotation, start.translation.normalize());
    let mut rows = relative_pose_residuals(&pose, x1, x2);
    let mut current = cost(&rows);
    let mut mu = 1e-4;
    for _ in 0..50 {
        let mut h = SMatrix::<f64, 5, 5>::zeros();
        let mut g = SVector::<f64, 5>::zeros();
        for (i, (r, j)) in rows.iter().enumerate() {
            let w = weights.map_or(1.0, |w| w[i]);
            let jv = SVector::<f64, 5>::from_row_slice(j);
            h += jv * jv.transpose() * w;
            g += jv * (r * w);
        }
        let mut accepted = false;
        for _ in 0..10 {
            let mut damped = h;
            for k in 0..5 {
                damped[(k, k)] += mu * h[(k, k)].max(1e-18);
            }
            let Some(step) = damped.cholesky().map(|c| -c.solve(&g)) else {
                mu *= 10.0;
                continue;
            };
            let candidate =
                retract_relative_pose(&pose, &[step[0], step[1], step[2], step[3], step[4]]);
            let cand_rows = relative_pose_residuals(&candidate, x1, x2);
            let c = cost(&cand_rows);
            if c < current {
                let decrease = (current - c) / current.max(1e-300);
                pose = candidate;
                rows = cand_rows;
                current = c;
                mu = (mu * 0.3).max(1e-12);
                accepted = decrease > 1e-12;
                break;
            }
            mu *= 10.0;
        }
        if !accepted {
            break;
        }
    }
    Ok(pose)
}

/// The essential matrix `[t]× R` of a relative pose (unit translation), Frobenius-normalised.
pub fn essential_from_pose(pose: &Pose) -> Matrix3<f64> {
    let e = pose.translation.normalize().cross_matrix() * pose.rotation_matrix();
    e / e.norm()
}

/// RANSAC estimator of the essential matrix from calibrated rays. Residuals are Sampson distances
/// on the z = 1 plane scaled by `focal_px`, so the threshold is in pixels.
pub struct EssentialEstimator<'a> {
    /// Rays in the first camera.
    pub x1: &'a [Vector3<f64>],
    /// Rays in the second camera.
    pub x2: &'a [Vector3<f64>],
    /// Focal length in pixels, to express residuals in pixels.
    pub focal_px: f64,
}

impl Estimator for EssentialEstimator<'_> {
    type Model = Matrix3<f64>;
    const NAME: &'static str = "essential RANSAC";

    fn min_samples(&self) -> usize {
        5
    }
    fn num_data(&self) -> usize {
        self.x1.len().min(self.x2.len())
    }
    fn fit_minimal(&self, sample: &[usize], models: &mut Vec<Matrix3<f64>>) {
        let a: Vec<Vector3<f64>> = sample.iter().map(|&i| self.x1[i]).collect();
        let b: Vec<Vector3<f64>> = sample.iter().map(|&i| self.x2[i]).collect();
        if let Ok(sols) = five_point(&a, &b) {
            models.extend(sols);
        }
    }
    /// Decomposes the current model with the cheirality test on the inliers, then refines the
    /// pose on their Sampson errors (the linear eight-point fit is the fallback start).
    fn fit_nonminimal(
        &self,
        idx: &[usize],
        w: Option<&[f64]>,
        start: &Matrix3<f64>,
    ) -> Option<Matrix3<f64>> {
        let a: Vec<Vector3<f64>> = idx.iter().map(|&i| self.x1[i]).collect();
        let b: Vec<Vector3<f64>> = idx.iter().map(|&i| self.x2[i]).collect();
        let pose = match relative_pose_from_essential(start, &a, &b) {
            Ok((pose, _)) => pose,
            Err(_) => {
                let e = eight_point_essential(&a, &b, w).ok()?;
                relative_pose_from_essential(&e, &a, &b).ok()?.0
            }
        };
        let refined = refine_relative_pose(&pose, &a, &b, w).ok()?;
        Some(essential_from_pose(&refined))
    }
    fn residual_sq(&self, e: &Matrix3<f64>, i: usize) -> f64 {
        sampson_distance_sq(e, &self.x1[i], &self.x2[i]) * self.focal_px * self.focal_px
    }
}
