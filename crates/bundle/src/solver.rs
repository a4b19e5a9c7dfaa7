//! Levenberg–Marquardt on the reduced camera system.
//!
//! Each iteration linearises every observation once, accumulates the camera-side normal
//! equations `U`, the point blocks `V_j` and the coupling blocks `E = J_cᵀ W J_p`, then — for each
//! trial damping — eliminates the points (`S = U − Σ_j E_j V_j⁻¹ E_jᵀ`), solves for the camera-side
//! step and back-substitutes the point steps. Damping, step acceptance and the three termination
//! tests follow Ceres's Levenberg–Marquardt, so final costs compare with Ceres's.

use nalgebra::{DVector, Matrix3, SMatrix, Vector3, Vector6};
use timesift_core::camera::MAX_INTRINSICS;
use timesift_core::{CameraModel, project_world, project_world_with_jacobians};

use crate::problem::{BundleProblem, CenterPrior, PointPrior};
use crate::reduced::{Reduced, SparsePattern};
use crate::{BundleError, Loss};

/// Options of [`solve`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BundleOptions {
    /// Robust loss on each observation's squared, sigma-normalised residual.
    pub loss: Loss,
    /// Most iterations.
    pub max_iterations: usize,
    /// Stop when a successful step changes the cost by less than this fraction.
    pub function_tolerance: f64,
    /// Stop when the largest gradient component falls below this.
    pub gradient_tolerance: f64,
    /// Stop when the step is smaller than this fraction of the parameter norm.
    pub parameter_tolerance: f64,
    /// Initial trust-region radius (inverse damping).
    pub initial_trust_region_radius: f64,
    /// How the reduced camera system is stored and factored.
    pub linear_solver: LinearSolver,
}

/// Storage and factorisation of the reduced camera system.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinearSolver {
    /// Dense up to [`DENSE_LIMIT`] camera-side parameters, sparse beyond.
    Auto,
    /// Dense Cholesky.
    DenseSchur,
    /// Sparse Cholesky with the symbolic analysis done once per solve.
    SparseSchur,
}

/// Largest number of camera-side parameters solved densely by [`LinearSolver::Auto`].
pub const DENSE_LIMIT: usize = 1000;

/// Largest number of camera-side parameters solved densely by [`LinearSolver::Auto`] when the
/// reduced system is more than a quarter full anyway.
pub const DENSE_FILL_LIMIT: usize = 6000;

impl Default for BundleOptions {
    fn default() -> Self {
        BundleOptions {
            loss: Loss::Trivial,
            max_iterations: 500,
            function_tolerance: 1e-6,
            gradient_tolerance: 1e-10,
            parameter_tolerance: 1e-8,
            initial_trust_region_radius: 1e4,
            linear_solver: LinearSolver::Auto,
        }
    }
}

/// Why the solver stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Termination {
    /// Relative cost change below the function tolerance.
    FunctionTolerance,
    /// Gradient below the gradient tolerance.
    GradientTolerance,
    /// Step below the parameter tolerance.
    ParameterTolerance,
    /// Iteration limit reached.
    MaxIterations,
    /// The damping grew without finding a decrease.
    NoProgress,
}

/// What a solve did.
#[derive(Debug, Clone, PartialEq)]
pub struct BundleReport {
    /// Cost ½ Σ ρ(s) before.
    pub initial_cost: f64,
    /// Cost after.
    pub final_cost: f64,
    /// Iterations (linearisations).
    pub iterations: usize,
    /// Accepted steps.
    pub successful_steps: usize,
    /// Why it stopped.
    pub termination: Termination,
    /// Root mean square reprojection error after, pixels: `sqrt(Σ‖u − û‖² / n)` over the
    /// observations that project (the per-observation norm, as in reports).
    pub rms_px: f64,
    /// Observations whose point ended behind its camera (left out of `rms_px`).
    pub unprojected: usize,
}

/// Index layout of the camera-side parameters.
pub(crate) struct Layout {
    pub(crate) pose_offset: Vec<Option<usize>>,
    pub(crate) group_offset: Vec<Option<usize>>,
    pub(crate) group_free: Vec<Vec<usize>>,
    pub(crate) point_index: Vec<Option<usize>>,
    pub(crate) num_camera_params: usize,
    pub(crate) num_free_points: usize,
}

impl Layout {
    pub(crate) fn new(p: &BundleProblem) -> Self {
        let mut n = 0;
        let pose_offset = p
            .images
            .iter()
            .map(|im| {
                (!im.fixed).then(|| {
                    n += 6;
                    n - 6
                })
            })
            .collect();
        let group_free: Vec<Vec<usize>> = p
            .groups
            .iter()
            .map(|g| {
                g.free
                    .iter()
                    .enumerate()
                    .filter(|(_, f)| **f)
                    .map(|(k, _)| k)
                    .collect()
            })
            .collect();
        let group_offset = group_free
            .iter()
            .map(|f| {
                (!f.is_empty()).then(|| {
                    n += f.len();
                    n - f.len()
                })
            })
            .collect();
        let mut m = 0;
        let point_index = p
            .points
            .iter()
            .map(|pt| {
                (!pt.fixed).then(|| {
                    m += 1;
                    m - 1
                })
            })
            .collect();
        Layout {
            pose_offset,
            group_offset,
            group_free,
            point_index,
            num_camera_params: n,
            num_free_points: m,
        }
    }
}

/// The normal equations of one linearisation, before damping.
struct Normal {
    u: Reduced,
    g_c: DVector<f64>,
    v: Vec<Matrix3<f64>>,
    g_p: Vec<Vector3<f64>>,
    /// Per observation: global camera-side columns (start, count) into `cols`.
    obs_cols: Vec<(usize, usize)>,
    cols: Vec<usize>,
    /// Per observation: E = w J_cᵀ J_p, row-major (count × 3), starting at `obs_cols.0 * 3`.
    e: Vec<f64>,
    /// Observations of each free point.
    point_obs: Vec<Vec<usize>>,
    cost: f64,
}

/// The reduced camera system `S = U − E V⁻¹ Eᵀ` of the squared (non-robust) cost at the current
/// parameters, undamped: the inverse of the camera-side block of the normal matrix, whose inverse
/// is the covariance of the camera-side parameters. `None` when a point block is singular.
pub(crate) fn reduced_system(
    p: &BundleProblem,
    layout: &Layout,
) -> Result<Option<Reduced>, BundleError> {
    let storage = reduced_storage(p, layout, LinearSolver::Auto)?;
    let nm = linearize(p, layout, &Loss::Trivial, &storage);
    let mut s = nm.u.clone();
    let mut rhs = nm.g_c.clone();
    let n = rhs.len();
    let ok = match &mut s {
        Reduced::Dense(m) => {
            let data = m.as_mut_slice();
            eliminate_points(&nm, 0.0, &mut rhs, |r, c, v| data[r + c * n] += v).is_some()
        }
        sparse => eliminate_points(&nm, 0.0, &mut rhs, |r, c, v| sparse.add(r, c, v)).is_some(),
    };
    Ok(ok.then_some(s))
}

/// Camera-centre prior residual (sigma-weighted) and its Jacobian with respect to the pose update
/// of `Pose::retract`: `C = −Rᵀ t`, `dC/dδω = −Rᵀ [t]×`, `dC/dδt = −Rᵀ`.
pub(crate) fn center_prior_residual(
    pose: &timesift_core::Pose,
    prior: &CenterPrior,
) -> (Vector3<f64>, SMatrix<f64, 3, 6>) {
    let inv = Vector3::new(
        1.0 / prior.sigma_xy,
        1.0 / prior.sigma_xy,
        1.0 / prior.sigma_z,
    );
    let r = (pose.center() - prior.position).component_mul(&inv);
    let rt = pose.rotation_matrix().transpose();
    let d_omega = -rt * pose.translation.cross_matrix();
    let mut j = SMatrix::<f64, 3, 6>::zeros();
    for row in 0..3 {
        for c in 0..3 {
            j[(row, c)] = d_omega[(row, c)] * inv[row];
            j[(row, 3 + c)] = -rt[(row, c)] * inv[row];
        }
    }
    (r, j)
}

fn point_prior_scale(prior: &PointPrior) -> Vector3<f64> {
    Vector3::new(
        1.0 / prior.sigma_xy,
        1.0 / prior.sigma_xy,
        1.0 / prior.sigma_z,
    )
}

fn prior_cost(p: &BundleProblem) -> f64 {
    let centres: f64 = p
        .center_priors
        .iter()
        .map(|c| {
            0.5 * center_prior_residual(&p.images[c.image].pose, c)
                .0
                .norm_squared()
        })
        .sum();
    let points: f64 = p
        .point_priors
        .iter()
        .map(|c| {
            0.5 * (p.points[c.point].position - c.position)
                .component_mul(&point_prior_scale(c))
                .norm_squared()
        })
        .sum();
    centres + points
}

/// Observations per parallel chunk; fixed so that the summation order, and so the result, does not
/// depend on the thread count.
const COST_CHUNK: usize = 4096;

fn cost_of(p: &BundleProblem, loss: &Loss) -> f64 {
    use rayon::prelude::*;
    let partial: Vec<f64> = p
        .observations
        .par_chunks(COST_CHUNK)
        .map(|chunk| {
            chunk
                .iter()
                .map(|o| {
                    let im = &p.images[o.image];
                    let cam = &p.groups[im.group].camera;
                    match project_world(cam, &im.pose, &p.points[o.point].position) {
                        Ok(px) => {
                            0.5 * loss
                                .evaluate(((px - o.pixel) / o.sigma_px).norm_squared())
                                .0
                        }
                        // A point behind a camera costs as much as a very large residual.
                        Err(_) => 0.5 * loss.evaluate(1e12).0,
                    }
                })
                .sum::<f64>()
        })
        .collect();
    prior_cost(p) + partial.iter().sum::<f64>()
}

fn linearize(p: &BundleProblem, layout: &Layout, loss: &Loss, storage: &Reduced) -> Normal {
    let n = layout.num_camera_params;
    let mut nm = Normal {
        u: storage.clone(),
        g_c: DVector::zeros(n),
        v: vec![Matrix3::zeros(); layout.num_free_points],
        g_p: vec![Vector3::zeros(); layout.num_free_points],
        obs_cols: Vec::with_capacity(p.observations.len()),
        cols: Vec::with_capacity(p.observations.len() * 9),
        e: Vec::with_capacity(p.observations.len() * 27),
        point_obs: vec![Vec::new(); layout.num_free_points],
        cost: 0.0,
    };
    let mut d_int = [0.0; 2 * MAX_INTRINSICS];
    let mut jc = [[0.0f64; 6 + MAX_INTRINSICS]; 2];
    for (k, o) in p.observations.iter().enumerate() {
        let im = &p.images[o.image];
        let cam = &p.groups[im.group].camera;
        let np = cam.num_params();
        let x = &p.points[o.point].position;
        let start = nm.cols.len();
        let Ok(j) = project_world_with_jacobians(cam, &im.pose, x, Some(&mut d_int[..2 * np]))
        else {
            nm.cost += 0.5 * loss.evaluate(1e12).0;
            nm.obs_cols.push((start, 0));
            continue;
        };
        let r = (j.pixel - o.pixel) / o.sigma_px;
        let (rho, w) = loss.evaluate(r.norm_squared());
        nm.cost += 0.5 * rho;
        let inv_sigma = 1.0 / o.sigma_px;
        // Camera-side Jacobian columns.
        let mut count = 0;
        if let Some(off) = layout.pose_offset[o.image] {
            for c in 0..6 {
                jc[0][count] = j.d_pose[(0, c)] * inv_sigma;
                jc[1][count] = j.d_pose[(1, c)] * inv_sigma;
                nm.cols.push(off + c);
                count += 1;
            }
        }
        if let Some(off) = layout.group_offset[im.group] {
            for (q, &param) in layout.group_free[im.group].iter().enumerate() {
                jc[0][count] = d_int[param] * inv_sigma;
                jc[1][count] = d_int[np + param] * inv_sigma;
                nm.cols.push(off + q);
                count += 1;
            }
        }
        nm.obs_cols.push((start, count));
        let cols = &nm.cols[start..start + count];
        for a in 0..count {
            nm.g_c[cols[a]] += w * (jc[0][a] * r.x + jc[1][a] * r.y);
            for b in 0..count {
                nm.u.add(
                    cols[a],
                    cols[b],
                    w * (jc[0][a] * jc[0][b] + jc[1][a] * jc[1][b]),
                );
            }
        }
        if let Some(pi) = layout.point_index[o.point] {
            let jp = j.d_world_point * inv_sigma;
            nm.v[pi] += jp.transpose() * jp * w;
            nm.g_p[pi] += jp.transpose() * r * w;
            for a in 0..count {
                for c in 0..3 {
                    nm.e.push(w * (jc[0][a] * jp[(0, c)] + jc[1][a] * jp[(1, c)]));
                }
            }
            nm.point_obs[pi].push(k);
        } else {
            nm.e.extend(std::iter::repeat_n(0.0, 3 * count));
        }
    }
    for c in &p.center_priors {
        let Some(off) = layout.pose_offset[c.image] else {
            nm.cost += 0.5
                * center_prior_residual(&p.images[c.image].pose, c)
                    .0
                    .norm_squared();
            continue;
        };
        let (r, j) = center_prior_residual(&p.images[c.image].pose, c);
        nm.cost += 0.5 * r.norm_squared();
        let jtj = j.transpose() * j;
        let jtr = j.transpose() * r;
        for a in 0..6 {
            nm.g_c[off + a] += jtr[a];
            for b in 0..6 {
                nm.u.add(off + a, off + b, jtj[(a, b)]);
            }
        }
    }
    for c in &p.point_priors {
        let scale = point_prior_scale(c);
        let r = (p.points[c.point].position - c.position).component_mul(&scale);
        nm.cost += 0.5 * r.norm_squared();
        if let Some(pi) = layout.point_index[c.point] {
            for k in 0..3 {
                nm.v[pi][(k, k)] += scale[k] * scale[k];
                nm.g_p[pi][k] += scale[k] * r[k];
            }
        }
    }
    nm
}

/// The damped step: camera-side and per free point.
struct Step {
    cameras: DVector<f64>,
    points: Vec<Vector3<f64>>,
}

/// Eliminates the points: `S −= E_a V⁻¹ E_bᵀ` over pairs of observations of each point (upper
/// pairs, mirrored) and `rhs −= E_a V⁻¹ g_p`; returns the damped `V⁻¹` of every point.
fn eliminate_points(
    nm: &Normal,
    lambda: f64,
    rhs: &mut DVector<f64>,
    mut add: impl FnMut(usize, usize, f64),
) -> Option<Vec<Matrix3<f64>>> {
    let clamp = |d: f64| d.clamp(1e-6, 1e32);
    let mut v_inv = Vec::with_capacity(nm.v.len());
    for (pi, v) in nm.v.iter().enumerate() {
        let mut vd = *v;
        for c in 0..3 {
            vd[(c, c)] += lambda * clamp(v[(c, c)]);
        }
        let inv = vd.try_inverse()?;
        let obs = &nm.point_obs[pi];
        let vg = inv * nm.g_p[pi];
        for (ia, &a) in obs.iter().enumerate() {
            let (sa, ca) = nm.obs_cols[a];
            let ea = &nm.e[sa * 3..(sa + ca) * 3];
            // F_a = E_a V⁻¹, row by row.
            let mut fa = [[0.0f64; 3]; 6 + MAX_INTRINSICS];
            for ra in 0..ca {
                let (e0, e1, e2) = (ea[3 * ra], ea[3 * ra + 1], ea[3 * ra + 2]);
                for c in 0..3 {
                    fa[ra][c] = e0 * inv[(0, c)] + e1 * inv[(1, c)] + e2 * inv[(2, c)];
                }
                rhs[nm.cols[sa + ra]] -= e0 * vg[0] + e1 * vg[1] + e2 * vg[2];
            }
            for &b in &obs[ia..] {
                let (sb, cb) = nm.obs_cols[b];
                let eb = &nm.e[sb * 3..(sb + cb) * 3];
                let cols_b = &nm.cols[sb..sb + cb];
                for ra in 0..ca {
                    let row = nm.cols[sa + ra];
                    let f = fa[ra];
                    for (rb, &col) in cols_b.iter().enumerate() {
                        let v = f[0] * eb[3 * rb] + f[1] * eb[3 * rb + 1] + f[2] * eb[3 * rb + 2];
                        add(row, col, -v);
                        if a != b {
                            add(col, row, -v);
                        }
                    }
                }
            }
        }
        v_inv.push(inv);
    }
    Some(v_inv)
}

fn damped_step(nm: &Normal, lambda: f64) -> Option<Step> {
    let n = nm.g_c.len();
    let clamp = |d: f64| d.clamp(1e-6, 1e32);
    let mut s = nm.u.clone();
    for i in 0..n {
        s.add(i, i, lambda * clamp(nm.u.diagonal(i)));
    }
    let mut rhs = nm.g_c.clone();
    // One monomorphised elimination per storage, so the dense inner loop indexes a slice.
    let v_inv = match &mut s {
        Reduced::Dense(m) => {
            let data = m.as_mut_slice();
            eliminate_points(nm, lambda, &mut rhs, |r, c, v| data[r + c * n] += v)?
        }
        sparse => eliminate_points(nm, lambda, &mut rhs, |r, c, v| sparse.add(r, c, v))?,
    };
    let cameras = if n > 0 {
        -s.solve(&rhs)?
    } else {
        DVector::zeros(0)
    };
    let points = nm
        .point_obs
        .iter()
        .enumerate()
        .map(|(pi, obs)| {
            let mut acc = nm.g_p[pi];
            for &a in obs {
                let (sa, ca) = nm.obs_cols[a];
                for ra in 0..ca {
                    let d = cameras[nm.cols[sa + ra]];
                    let e = &nm.e[(sa + ra) * 3..(sa + ra) * 3 + 3];
                    acc += Vector3::new(e[0], e[1], e[2]) * d;
                }
            }
            -(v_inv[pi] * acc)
        })
        .collect();
    Some(Step { cameras, points })
}

fn apply_step(p: &BundleProblem, layout: &Layout, step: &Step) -> Option<BundleProblem> {
    let mut q = p.clone();
    for (i, im) in q.images.iter_mut().enumerate() {
        if let Some(off) = layout.pose_offset[i] {
            let d = Vector6::from_iterator((0..6).map(|c| step.cameras[off + c]));
            im.pose = im.pose.retract(&d);
        }
    }
    for (g, group) in q.groups.iter_mut().enumerate() {
        if let Some(off) = layout.group_offset[g] {
            let mut params = [0.0; MAX_INTRINSICS];
            let n = group.camera.num_params();
            group.camera.params(&mut params[..n]);
            for (q, &k) in layout.group_free[g].iter().enumerate() {
                params[k] += step.cameras[off + q];
            }
            // An invalid update (e.g. f ≤ 0) rejects the whole step: the damping then grows.
            group.camera.set_params(&params[..n]).ok()?;
        }
    }
    for (j, pt) in q.points.iter_mut().enumerate() {
        if let Some(pi) = layout.point_index[j] {
            pt.position += step.points[pi];
        }
    }
    Some(q)
}

fn parameter_norm(p: &BundleProblem) -> f64 {
    let mut s = 0.0;
    for im in &p.images {
        s += im.pose.translation.norm_squared() + 1.0;
    }
    for g in &p.groups {
        let mut params = [0.0; MAX_INTRINSICS];
        let n = g.camera.num_params();
        g.camera.params(&mut params[..n]);
        s += params[..n].iter().map(|v| v * v).sum::<f64>();
    }
    for pt in &p.points {
        s += pt.position.norm_squared();
    }
    s.sqrt()
}

/// Root mean square of the reprojection error vectors (pixels, per observation), and the number of
/// observations that do not project (behind their camera), which the RMS leaves out.
fn reprojection_rms(p: &BundleProblem) -> (f64, usize) {
    let (mut sum, mut n, mut lost) = (0.0, 0usize, 0usize);
    for o in &p.observations {
        let im = &p.images[o.image];
        match project_world(
            &p.groups[im.group].camera,
            &im.pose,
            &p.points[o.point].position,
        ) {
            Ok(px) => {
                sum += (px - o.pixel).norm_squared();
                n += 1;
            }
            Err(_) => lost += 1,
        }
    }
    (if n == 0 { 0.0 } else { (sum / n as f64).sqrt() }, lost)
}

/// Camera-side columns of an observation.
fn observation_columns(p: &BundleProblem, layout: &Layout, image: usize) -> Vec<usize> {
    let mut cols = Vec::new();
    if let Some(off) = layout.pose_offset[image] {
        cols.extend(off..off + 6);
    }
    let g = p.images[image].group;
    if let Some(off) = layout.group_offset[g] {
        cols.extend(off..off + layout.group_free[g].len());
    }
    cols
}

/// Empty storage of the reduced system for the chosen solver; the sparse pattern couples the
/// columns of each observation and of all observations of each free point.
fn reduced_storage(
    p: &BundleProblem,
    layout: &Layout,
    solver: LinearSolver,
) -> Result<Reduced, BundleError> {
    let n = layout.num_camera_params;
    let sparse = match solver {
        LinearSolver::DenseSchur => false,
        LinearSolver::SparseSchur => true,
        LinearSolver::Auto => n > DENSE_LIMIT,
    };
    if !sparse || n == 0 {
        return Ok(Reduced::dense(n));
    }
    let mut groups: Vec<Vec<usize>> = Vec::new();
    let mut per_point: Vec<Vec<usize>> = vec![Vec::new(); layout.num_free_points];
    for o in &p.observations {
        let cols = observation_columns(p, layout, o.image);
        if let Some(pi) = layout.point_index[o.point] {
            per_point[pi].extend_from_slice(&cols);
        }
        groups.push(cols);
    }
    for c in &p.center_priors {
        if let Some(off) = layout.pose_offset[c.image] {
            groups.push((off..off + 6).collect());
        }
    }
    for mut cols in per_point {
        cols.sort_unstable();
        cols.dedup();
        groups.push(cols);
    }
    let pattern = SparsePattern::new(n, &groups).ok_or_else(|| {
        BundleError::InvalidProblem("symbolic analysis of the reduced system failed".to_string())
    })?;
    // Few points seen by many cameras make `S` nearly full: then dense storage (direct indexing,
    // dense Cholesky) beats sparse, up to a size where n² memory stays modest.
    let density = pattern.nnz_lower() as f64 / (0.5 * n as f64 * (n + 1) as f64);
    if solver == LinearSolver::Auto && density > 0.25 && n <= DENSE_FILL_LIMIT {
        return Ok(Reduced::dense(n));
    }
    Ok(Reduced::sparse(pattern))
}

/// Adjusts the problem in place and reports what happened.
pub fn solve(
    problem: &mut BundleProblem,
    options: &BundleOptions,
) -> Result<BundleReport, BundleError> {
    problem.validate()?;
    options.loss.validate()?;
    let layout = Layout::new(problem);
    if layout.num_camera_params == 0 && layout.num_free_points == 0 {
        return Err(BundleError::NothingToAdjust);
    }
    let initial_cost = cost_of(problem, &options.loss);
    let mut cost = initial_cost;
    let mut radius = options.initial_trust_region_radius;
    let mut nu = 2.0;
    let mut iterations = 0;
    let mut successful_steps = 0;
    let mut termination = Termination::MaxIterations;
    let storage = reduced_storage(problem, &layout, options.linear_solver)?;
    let mut nm = linearize(problem, &layout, &options.loss, &storage);
    while iterations < options.max_iterations {
        iterations += 1;
        let g_max = nm
            .g_c
            .iter()
            .chain(nm.g_p.iter().flat_map(|g| g.iter()))
            .fold(0.0f64, |m, v| m.max(v.abs()));
        if g_max <= options.gradient_tolerance {
            termination = Termination::GradientTolerance;
            break;
        }
        let lambda = 1.0 / radius;
        let Some(step) = damped_step(&nm, lambda) else {
            radius /= nu;
            nu *= 2.0;
            if radius < 1e-32 {
                termination = Termination::NoProgress;
                break;
            }
            continue;
        };
        // Predicted decrease of the linear model: ½ (λ δᵀDδ − gᵀδ).
        let clamp = |d: f64| d.clamp(1e-6, 1e32);
        let mut model = 0.0;
        for i in 0..step.cameras.len() {
            let d = step.cameras[i];
            model += lambda * clamp(nm.u.diagonal(i)) * d * d - nm.g_c[i] * d;
        }
        let mut step_sq = step.cameras.norm_squared();
        for (pi, d) in step.points.iter().enumerate() {
            for c in 0..3 {
                model += lambda * clamp(nm.v[pi][(c, c)]) * d[c] * d[c] - nm.g_p[pi][c] * d[c];
            }
            step_sq += d.norm_squared();
        }
        model *= 0.5;
        let x_norm = parameter_norm(problem);
        if step_sq.sqrt() <= options.parameter_tolerance * (x_norm + options.parameter_tolerance) {
            termination = Termination::ParameterTolerance;
            break;
        }
        let Some(candidate) = apply_step(problem, &layout, &step) else {
            radius /= nu;
            nu *= 2.0;
            if radius < 1e-32 {
                termination = Termination::NoProgress;
                break;
            }
            continue;
        };
        let new_cost = cost_of(&candidate, &options.loss);
        let rho = (cost - new_cost) / model.max(f64::MIN_POSITIVE);
        if new_cost.is_finite() && new_cost < cost && rho > 1e-3 {
            let decrease = (cost - new_cost) / cost;
            *problem = candidate;
            cost = new_cost;
            successful_steps += 1;
            radius /= (1.0f64 / 3.0).max(1.0 - (2.0 * rho - 1.0).powi(3));
            radius = radius.min(1e16);
            nu = 2.0;
            if decrease <= options.function_tolerance {
                termination = Termination::FunctionTolerance;
                break;
            }
            nm = linearize(problem, &layout, &options.loss, &storage);
        } else {
            radius /= nu;
            nu *= 2.0;
            if radius < 1e-32 {
                termination = Termination::NoProgress;
                break;
            }
        }
    }
    let (rms_px, unprojected) = reprojection_rms(problem);
    Ok(BundleReport {
        initial_cost,
        final_cost: cost,
        iterations,
        successful_steps,
        termination,
        rms_px,
        unprojected,
    })
}

/// Number of adjusted parameters in the local (update) coordinates used by [`gradient`] and
/// [`perturbed`]: free poses (6 each), free intrinsics, then free points (3 each).
pub fn num_parameters(problem: &BundleProblem) -> usize {
    let layout = Layout::new(problem);
    layout.num_camera_params + 3 * layout.num_free_points
}

/// Cost ½ Σ ρ(‖r/σ‖²) of the reprojections plus ½ Σ ‖r/σ‖² of the priors.
pub fn cost(problem: &BundleProblem, loss: &Loss) -> f64 {
    cost_of(problem, loss)
}

/// Gradient of [`cost`] in local coordinates, from the analytic Jacobians the solver uses; exposed
/// so that tools and tests can check those Jacobians against finite differences of the cost.
pub fn gradient(problem: &BundleProblem, loss: &Loss) -> Vec<f64> {
    let layout = Layout::new(problem);
    let storage = Reduced::dense(layout.num_camera_params);
    let nm = linearize(problem, &layout, loss, &storage);
    let mut g: Vec<f64> = nm.g_c.iter().copied().collect();
    for gp in &nm.g_p {
        g.extend(gp.iter());
    }
    g
}

/// The problem moved by a local update `delta` (length [`num_parameters`]).
pub fn perturbed(problem: &BundleProblem, delta: &[f64]) -> Option<BundleProblem> {
    let layout = Layout::new(problem);
    let n = layout.num_camera_params;
    let step = Step {
        cameras: DVector::from_iterator(n, delta[..n].iter().copied()),
        points: delta[n..]
            .chunks(3)
            .map(|c| Vector3::new(c[0], c[1], c[2]))
            .collect(),
    };
    apply_step(problem, &layout, &step)
}
