//! Levenberg–Marquardt on the reduced camera system.
//!
//! Each iteration linearises every observation once, accumulates the camera-side normal
//! equations `U`, the point blocks `V_j` and the coupling blocks `E = J_cᵀ W J_p`, then — for each
//! trial damping — eliminates the points (`S = U − Σ_j E_j V_j⁻¹ E_jᵀ`), solves for the camera-side
//! step and back-substitutes the point steps. Damping, step acceptance and the three termination
//! tests follow Ceres's Levenberg–Marquardt, so final costs compare with Ceres's.

use std::sync::OnceLock;

use nalgebra::{DMatrix, DVector, SMatrix, SVector, Vector2, Vector3, Vector6};
use timesift_core::camera::MAX_INTRINSICS;
use timesift_core::{
    CameraModel, ProjectionJacobians, project_world, project_world_with_jacobians,
};

use crate::coarse::CoarseSpace;
use crate::layout::{Eliminate, Layout};
use crate::problem::{BundleProblem, CenterPrior, Observation, PriorOffset, ScaleBar};
use crate::reduced::{Reduced, SparsePattern};
use crate::schur::{self, BlockRows, Coupling, damped_inverses};
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
    /// Which blocks the Schur complement eliminates.
    pub elimination: Elimination,
    /// Forcing tolerance of the conjugate-gradient solvers (Ceres's `eta`): a step's conjugate
    /// gradients stop once an iteration `i` lowers the quadratic model `Q` by less than
    /// `eta / i` of `Q` so far (Nash and Sofer's truncated-Newton test), or at a relative
    /// residual of [`PCG_RESIDUAL_FLOOR`]; 0 runs them to that residual. Why: the damped step
    /// only needs to decrease the cost, and an exact solve of each trial system costs several
    /// times the products an inexact one needs, and the Levenberg–Marquardt iterations correct
    /// what an inexact step leaves.
    pub linear_tolerance: f64,
}

/// Which parameter blocks the Schur complement eliminates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Elimination {
    /// Whichever leaves the smaller reduced system (the default).
    Auto,
    /// The points (many points, fewer cameras: photogrammetric blocks).
    Points,
    /// The camera poses (many cameras, few points: camera tracking).
    Poses,
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
    /// Conjugate gradients on the reduced system without forming it (products through the
    /// eliminated blocks), preconditioned by its block diagonal (Schur–Jacobi): memory linear in
    /// the observations, for very large blocks.
    IterativeSchur,
    /// Conjugate gradients on the formed (sparse) reduced system, preconditioned by its block
    /// diagonal and a coarse level of the cameras' joint motions (tiles of ground shifted,
    /// turned, scaled; each intrinsic with the cameras' response to it): memory of the reduced
    /// system's non-zeros, never its factor's fill-in; what [`LinearSolver::Auto`] picks for
    /// large systems with many non-zeros (see [`ITERATIVE_FROM`]).
    SparseIterativeSchur,
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
            elimination: Elimination::Auto,
            linear_tolerance: PCG_FORCING,
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
    /// Conjugate-gradient iterations over all trial steps (0 when every step was solved by
    /// Cholesky).
    pub linear_iterations: usize,
}

/// Most reduced-side columns of one observation: a pose, a point (scale-bar ends), every intrinsic.
const MAX_COLS: usize = 9 + MAX_INTRINSICS;

/// The normal equations of one linearisation, before damping, with eliminated blocks of size `D`.
struct Normal<const D: usize> {
    u: Reduced,
    g_c: DVector<f64>,
    v: Vec<SMatrix<f64, D, D>>,
    g_p: Vec<SVector<f64, D>>,
    /// Per observation: reduced-side columns (start, count) into `cols`.
    obs_cols: Vec<(usize, usize)>,
    cols: Vec<usize>,
    /// Per observation: E = w J_cᵀ J_e, row-major (count × D), starting at `obs_cols.0 * D`.
    e: Vec<f64>,
    /// Observations of each eliminated block.
    point_obs: Vec<Vec<usize>>,
    cost: f64,
    /// The blocks' rows merged and sorted for elimination, built on first use (the iterative
    /// solver never needs them).
    rows: OnceLock<BlockRows<D>>,
}

impl<const D: usize> Normal<D> {
    fn coupling(&self) -> Coupling<'_> {
        Coupling {
            obs_cols: &self.obs_cols,
            cols: &self.cols,
            e: &self.e,
            point_obs: &self.point_obs,
        }
    }

    fn block_rows(&self) -> &BlockRows<D> {
        self.rows.get_or_init(|| {
            BlockRows::new(
                self.g_c.len(),
                &self.coupling(),
                rayon::current_num_threads(),
            )
        })
    }
}

/// The reduced camera system `S = U − E V⁻¹ Eᵀ` of the squared (non-robust) cost at the current
/// parameters, points eliminated, undamped: its inverse is the covariance of the camera-side
/// parameters. `None` when a point block is singular.
pub(crate) fn reduced_system(
    p: &BundleProblem,
    layout: &Layout,
) -> Result<Option<Reduced>, BundleError> {
    let (storage, _) = reduced_storage(p, layout, LinearSolver::Auto, true)?;
    let nm = linearize::<3>(p, layout, &Loss::Trivial, &storage);
    drop(storage);
    let mut s = nm.u.clone();
    let mut rhs = nm.g_c.clone();
    let Some(v_inv) = damped_inverses(&nm.v, 0.0) else {
        return Ok(None);
    };
    schur::eliminate(nm.block_rows(), &v_inv, &nm.g_p, &mut s, &mut rhs);
    Ok(Some(s))
}

/// Jacobian of the camera centre `C = −Rᵀ t` with respect to the pose update of
/// `Pose::retract`: `dC/dδω = −Rᵀ [t]×`, `dC/dδt = −Rᵀ`.
pub(crate) fn center_jacobian(pose: &timesift_core::Pose) -> SMatrix<f64, 3, 6> {
    let rt = pose.rotation_matrix().transpose();
    let d_omega = -rt * pose.translation.cross_matrix();
    let mut j = SMatrix::<f64, 3, 6>::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&d_omega);
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-rt));
    j
}

/// Camera-centre prior residual (sigma-weighted) and its Jacobian with respect to the pose (see
/// [`center_jacobian`]); that with respect to the prior's offset, when it has one, is
/// `diag(1/σ)` ([`center_prior_scale`]).
pub(crate) fn center_prior_residual(
    p: &BundleProblem,
    prior: &CenterPrior,
) -> (Vector3<f64>, SMatrix<f64, 3, 6>) {
    let pose = &p.images[prior.image].pose;
    let inv = center_prior_scale(prior);
    let offset = prior
        .offset
        .map_or_else(Vector3::zeros, |o| p.prior_offsets[o].value);
    let r = (pose.center() - prior.position + offset).component_mul(&inv);
    let mut j = center_jacobian(pose);
    for row in 0..3 {
        for c in 0..6 {
            j[(row, c)] *= inv[row];
        }
    }
    (r, j)
}

/// `1/σ` per axis of a centre prior.
pub(crate) fn center_prior_scale(prior: &CenterPrior) -> Vector3<f64> {
    Vector3::new(
        1.0 / prior.sigma_xy,
        1.0 / prior.sigma_xy,
        1.0 / prior.sigma_z,
    )
}

/// `1/σ` per axis of a prior offset's zero-mean prior.
pub(crate) fn offset_prior_scale(offset: &PriorOffset) -> Vector3<f64> {
    Vector3::new(
        1.0 / offset.sigma_xy,
        1.0 / offset.sigma_xy,
        1.0 / offset.sigma_z,
    )
}

fn prior_cost(p: &BundleProblem) -> f64 {
    let centres: f64 = p
        .center_priors
        .iter()
        .map(|c| 0.5 * center_prior_residual(p, c).0.norm_squared())
        .sum();
    let offsets: f64 = p
        .prior_offsets
        .iter()
        .filter(|o| !o.fixed)
        .map(|o| 0.5 * o.value.component_mul(&offset_prior_scale(o)).norm_squared())
        .sum();
    let points: f64 = p
        .point_priors
        .iter()
        .map(|c| 0.5 * c.residual(&p.points[c.point].position).0.norm_squared())
        .sum();
    let bars: f64 = p
        .scale_bars
        .iter()
        .map(|bar| 0.5 * scale_bar_residual(p, bar).0.powi(2))
        .sum();
    centres + offsets + points + bars
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

fn linearize<const D: usize>(
    p: &BundleProblem,
    layout: &Layout,
    loss: &Loss,
    storage: &Reduced,
) -> Normal<D> {
    let poses_eliminated = layout.eliminate == Eliminate::Poses;
    debug_assert_eq!(D, if poses_eliminated { 6 } else { 3 });
    let mut nm = Normal::<D>::empty(p, layout, storage);
    nm.add_residuals(p, layout, loss);
    nm
}

/// One projected observation's linearisation: its σ-normalised residual, loss weight, and the
/// σ-scaled Jacobian rows on the reduced side (the first `count` columns of `jc`) and of its
/// eliminated block (`je`). One is reused as scratch across all observations.
struct ObservationRows<const D: usize> {
    r: Vector2<f64>,
    w: f64,
    jc: [[f64; MAX_COLS]; 2],
    count: usize,
    je: [[f64; D]; 2],
}

impl<const D: usize> ObservationRows<D> {
    /// Fills `je` with the σ-scaled Jacobian of the eliminated block: the pose's when poses are
    /// eliminated, the point's otherwise.
    fn set_eliminated(&mut self, j: &ProjectionJacobians, poses_eliminated: bool, inv_sigma: f64) {
        for c in 0..D {
            let (j0, j1) = if poses_eliminated {
                (j.d_pose[(0, c)], j.d_pose[(1, c)])
            } else {
                (j.d_world_point[(0, c)], j.d_world_point[(1, c)])
            };
            self.je[0][c] = j0 * inv_sigma;
            self.je[1][c] = j1 * inv_sigma;
        }
    }
}

/// Observations linearised in parallel at once by [`Normal::add_observations`] before they are
/// summed in order: enough to keep the threads busy, few enough that the batch's rows (some
/// 500 bytes each) stay small beside the normal equations.
const LINEARISE_BATCH: usize = 16_384;

/// One observation's rows and loss `ρ`, or `None` when its point does not project.
fn observation_rows<const D: usize>(
    p: &BundleProblem,
    layout: &Layout,
    loss: &Loss,
    o: &Observation,
    poses_eliminated: bool,
) -> Option<(ObservationRows<D>, f64)> {
    let im = &p.images[o.image];
    let cam = &p.groups[im.group].camera;
    let np = cam.num_params();
    let mut d_int = [0.0; 2 * MAX_INTRINSICS];
    let x = &p.points[o.point].position;
    let j = project_world_with_jacobians(cam, &im.pose, x, Some(&mut d_int[..2 * np])).ok()?;
    let r = (j.pixel - o.pixel) / o.sigma_px;
    let (rho, w) = loss.evaluate(r.norm_squared());
    let mut rows = ObservationRows::<D> {
        r,
        w,
        jc: [[0.0f64; MAX_COLS]; 2],
        count: 0,
        je: [[0.0f64; D]; 2],
    };
    rows.count = reduced_jacobian(layout, o, im.group, &j, &d_int[..2 * np], &mut rows.jc);
    if layout.eliminated(o.image, o.point).is_some() {
        rows.set_eliminated(&j, poses_eliminated, 1.0 / o.sigma_px);
    }
    Some((rows, rho))
}

/// Fills `jc` with an observation's σ-scaled reduced-side Jacobian — its pose or point
/// columns, then its group's free intrinsics (`d_int`: both pixel rows' derivatives), in
/// [`Layout::extend_observation_columns`]'s order; returns how many columns.
fn reduced_jacobian(
    layout: &Layout,
    o: &Observation,
    group: usize,
    j: &ProjectionJacobians,
    d_int: &[f64],
    jc: &mut [[f64; MAX_COLS]; 2],
) -> usize {
    let np = d_int.len() / 2;
    let inv_sigma = 1.0 / o.sigma_px;
    let mut count = 0;
    if layout.pose_offset[o.image].is_some() {
        for c in 0..6 {
            jc[0][count] = j.d_pose[(0, c)] * inv_sigma;
            jc[1][count] = j.d_pose[(1, c)] * inv_sigma;
            count += 1;
        }
    }
    if layout.point_offset[o.point].is_some() {
        for c in 0..3 {
            jc[0][count] = j.d_world_point[(0, c)] * inv_sigma;
            jc[1][count] = j.d_world_point[(1, c)] * inv_sigma;
            count += 1;
        }
    }
    if layout.group_offset[group].is_some() {
        for &param in &layout.group_free[group] {
            jc[0][count] = d_int[param] * inv_sigma;
            jc[1][count] = d_int[np + param] * inv_sigma;
            count += 1;
        }
    }
    count
}

impl<const D: usize> Normal<D> {
    /// Zeroed normal equations of the layout's sizes, the reduced side in `storage`'s form.
    fn empty(p: &BundleProblem, layout: &Layout, storage: &Reduced) -> Self {
        let n = layout.num_camera_params;
        // Exact upper bounds (an observation that does not project has no columns): grown by
        // doubling, `e` was the largest allocation of an adjustment and copied on every growth.
        let cols: usize = p
            .observations
            .iter()
            .map(|o| layout.observation_column_count(p, o.image, o.point))
            .sum();
        Normal::<D> {
            u: storage.clone(),
            g_c: DVector::zeros(n),
            v: vec![SMatrix::zeros(); layout.num_free_points],
            g_p: vec![SVector::zeros(); layout.num_free_points],
            obs_cols: Vec::with_capacity(p.observations.len()),
            cols: Vec::with_capacity(cols),
            e: Vec::with_capacity(cols * D),
            point_obs: vec![Vec::new(); layout.num_free_points],
            cost: 0.0,
            rows: OnceLock::new(),
        }
    }

    /// Adds every residual: observations, then priors and scale bars.
    fn add_residuals(&mut self, p: &BundleProblem, layout: &Layout, loss: &Loss) {
        self.add_observations(p, layout, loss);
        self.add_center_priors(p, layout);
        self.add_offset_priors(p, layout);
        self.add_point_priors(p, layout);
        self.add_scale_bars(p, layout);
    }

    /// Linearises again at the problem's current parameters, in this linearisation's storage
    /// (the same sums as a fresh [`linearize`]): a block of millions of observations otherwise
    /// allocates, and has the kernel zero, hundreds of megabytes per iteration (a third of an
    /// 800-image orientation's time went to page faults). The block rows are refilled when
    /// their structure still holds.
    fn relinearize(&mut self, p: &BundleProblem, layout: &Layout, loss: &Loss) {
        let rows = self.rows.take();
        self.u.clear();
        self.g_c.fill(0.0);
        self.v.fill(SMatrix::zeros());
        self.g_p.fill(SVector::zeros());
        self.obs_cols.clear();
        self.cols.clear();
        self.e.clear();
        for obs in &mut self.point_obs {
            obs.clear();
        }
        self.cost = 0.0;
        self.add_residuals(p, layout, loss);
        if let Some(mut rows) = rows
            && rows.refill(&self.coupling())
        {
            let _ = self.rows.set(rows);
        }
    }

    /// Adds every reprojection residual, in observation order: its cost, its reduced-side and
    /// eliminated blocks and their coupling `E` (zeros when nothing is eliminated, so that `e`
    /// stays aligned with `cols`). The projections and Jacobians of a batch of observations are
    /// computed in parallel, then summed one by one in observation order, so the sums are those
    /// of a serial pass whatever the threads (serial, the linearisation was a fifth of the align
    /// stage's time on 1,600 images).
    fn add_observations(&mut self, p: &BundleProblem, layout: &Layout, loss: &Loss) {
        use rayon::prelude::*;
        let poses_eliminated = layout.eliminate == Eliminate::Poses;
        let mut batch: Vec<Option<(ObservationRows<D>, f64)>> = Vec::new();
        for (b, observations) in p.observations.chunks(LINEARISE_BATCH).enumerate() {
            observations
                .par_iter()
                .map(|o| observation_rows::<D>(p, layout, loss, o, poses_eliminated))
                .collect_into_vec(&mut batch);
            for (q, (o, linearised)) in observations.iter().zip(&batch).enumerate() {
                let k = b * LINEARISE_BATCH + q;
                let start = self.cols.len();
                let Some((rows, rho)) = linearised else {
                    self.cost += 0.5 * loss.evaluate(1e12).0;
                    self.obs_cols.push((start, 0));
                    continue;
                };
                self.cost += 0.5 * rho;
                layout.extend_observation_columns(p, o.image, o.point, &mut self.cols);
                debug_assert_eq!(self.cols.len() - start, rows.count);
                self.obs_cols.push((start, rows.count));
                self.add_reduced_rows(start, rows);
                if let Some(bi) = layout.eliminated(o.image, o.point) {
                    self.add_eliminated_rows(bi, k, rows);
                } else {
                    self.e.extend(std::iter::repeat_n(0.0, D * rows.count));
                }
            }
        }
    }

    /// Adds `w Jcᵀ r` and `w Jcᵀ Jc` of an observation whose columns start at `start` in `cols`.
    fn add_reduced_rows(&mut self, start: usize, rows: &ObservationRows<D>) {
        let (jc, r, w, count) = (&rows.jc, &rows.r, rows.w, rows.count);
        let cols = &self.cols[start..start + count];
        for a in 0..count {
            self.g_c[cols[a]] += w * (jc[0][a] * r.x + jc[1][a] * r.y);
            for b in 0..count {
                self.u.add(
                    cols[a],
                    cols[b],
                    w * (jc[0][a] * jc[0][b] + jc[1][a] * jc[1][b]),
                );
            }
        }
    }

    /// Adds observation `k`'s `w Jeᵀ r` and `w Jeᵀ Je` to eliminated block `bi`, and appends its
    /// coupling `E = w Jcᵀ Je` (row-major) and the observation to the block's list.
    fn add_eliminated_rows(&mut self, bi: usize, k: usize, rows: &ObservationRows<D>) {
        let (jc, je, r, w, count) = (&rows.jc, &rows.je, &rows.r, rows.w, rows.count);
        let v = &mut self.v[bi];
        let g = &mut self.g_p[bi];
        for a in 0..D {
            g[a] += w * (je[0][a] * r.x + je[1][a] * r.y);
            for b in 0..D {
                v[(a, b)] += w * (je[0][a] * je[0][b] + je[1][a] * je[1][b]);
            }
        }
        for a in 0..count {
            for c in 0..D {
                self.e.push(w * (jc[0][a] * je[0][c] + jc[1][a] * je[1][c]));
            }
        }
        self.point_obs[bi].push(k);
    }

    /// Adds the camera-centre priors: on the reduced-side pose or on the eliminated pose block,
    /// and the blocks of their offset (its Jacobian is `diag(1/σ)`) with itself and the pose.
    fn add_center_priors(&mut self, p: &BundleProblem, layout: &Layout) {
        for c in &p.center_priors {
            let (r, j) = center_prior_residual(p, c);
            self.cost += 0.5 * r.norm_squared();
            let jtj = j.transpose() * j;
            let jtr = j.transpose() * r;
            let pose_off = layout.pose_offset[c.image];
            if let Some(off) = pose_off {
                for a in 0..6 {
                    self.g_c[off + a] += jtr[a];
                    for b in 0..6 {
                        self.u.add(off + a, off + b, jtj[(a, b)]);
                    }
                }
            } else if let Some(bi) = layout.pose_index[c.image] {
                for a in 0..6 {
                    self.g_p[bi][a] += jtr[a];
                    for b in 0..6 {
                        self.v[bi][(a, b)] += jtj[(a, b)];
                    }
                }
            }
            // The offset's Jacobian is diag(1/σ): its blocks with itself and with the pose.
            if let Some(bo) = c.offset.and_then(|o| layout.bias_offset[o]) {
                let scale = center_prior_scale(c);
                for a in 0..3 {
                    self.g_c[bo + a] += scale[a] * r[a];
                    self.u.add(bo + a, bo + a, scale[a] * scale[a]);
                }
                if let Some(off) = pose_off {
                    for a in 0..3 {
                        for b in 0..6 {
                            let v = scale[a] * j[(a, b)];
                            self.u.add(bo + a, off + b, v);
                            self.u.add(off + b, bo + a, v);
                        }
                    }
                }
            }
        }
    }

    /// Adds the zero-mean priors of the free prior offsets.
    fn add_offset_priors(&mut self, p: &BundleProblem, layout: &Layout) {
        for (o, offset) in p.prior_offsets.iter().enumerate() {
            let Some(bo) = layout.bias_offset[o] else {
                continue;
            };
            let scale = offset_prior_scale(offset);
            let r = offset.value.component_mul(&scale);
            self.cost += 0.5 * r.norm_squared();
            for a in 0..3 {
                self.g_c[bo + a] += scale[a] * r[a];
                self.u.add(bo + a, bo + a, scale[a] * scale[a]);
            }
        }
    }

    /// Adds the control-point priors, on the eliminated point block or the reduced-side point.
    fn add_point_priors(&mut self, p: &BundleProblem, layout: &Layout) {
        for c in &p.point_priors {
            let (r, j) = c.residual(&p.points[c.point].position);
            self.cost += 0.5 * r.norm_squared();
            let (jtj, jtr) = (j.transpose() * j, j.transpose() * r);
            if let Some(pi) = layout.point_index[c.point] {
                for k in 0..3 {
                    for l in 0..3 {
                        self.v[pi][(k, l)] += jtj[(k, l)];
                    }
                    self.g_p[pi][k] += jtr[k];
                }
            } else if let Some(off) = layout.point_offset[c.point] {
                for k in 0..3 {
                    for l in 0..3 {
                        if jtj[(k, l)] != 0.0 {
                            self.u.add(off + k, off + l, jtj[(k, l)]);
                        }
                    }
                    self.g_c[off + k] += jtr[k];
                }
            }
        }
    }

    /// Adds the scale bars; their free ends are always on the reduced side.
    fn add_scale_bars(&mut self, p: &BundleProblem, layout: &Layout) {
        for bar in &p.scale_bars {
            let (r, ja) = scale_bar_residual(p, bar);
            self.cost += 0.5 * r * r;
            let ends = [
                (layout.point_offset[bar.a], ja),
                (layout.point_offset[bar.b], -ja),
            ];
            for &(oa, ja) in &ends {
                let Some(oa) = oa else { continue };
                for k in 0..3 {
                    self.g_c[oa + k] += ja[k] * r;
                }
                for &(ob, jb) in &ends {
                    let Some(ob) = ob else { continue };
                    for k in 0..3 {
                        for l in 0..3 {
                            self.u.add(oa + k, ob + l, ja[k] * jb[l]);
                        }
                    }
                }
            }
        }
    }
}

/// Scale-bar residual `(‖X_a − X_b‖ − L) / σ` and its gradient with respect to `X_a` (that with
/// respect to `X_b` is the opposite).
pub(crate) fn scale_bar_residual(p: &BundleProblem, bar: &ScaleBar) -> (f64, Vector3<f64>) {
    let d = p.points[bar.a].position - p.points[bar.b].position;
    let len = d.norm();
    let r = (len - bar.length) / bar.sigma;
    let j = if len > 0.0 {
        d / (len * bar.sigma)
    } else {
        Vector3::zeros()
    };
    (r, j)
}

/// The damped step: reduced side and per eliminated block.
struct Step<const D: usize> {
    cameras: DVector<f64>,
    points: Vec<SVector<f64, D>>,
}

/// How the trial steps of one solve are solved, and what the iterative methods use.
#[derive(Clone, Copy)]
struct StepSolver<'a> {
    how: StepSolve,
    /// The block-Jacobi preconditioner's parameter blocks (empty for [`StepSolve::Factor`]).
    blocks: &'a [Vec<usize>],
    /// The coarse level of [`StepSolve::FormedCg`].
    coarse: Option<&'a CoarseSpace>,
    /// [`BundleOptions::linear_tolerance`].
    tolerance: f64,
}

/// `s`: storage for the damped reduced system, of `nm.u`'s shape, reused from step to step (on
/// a block of hundreds of images it is tens of megabytes, fresh pages every time if allocated).
fn damped_step<const D: usize>(
    nm: &Normal<D>,
    lambda: f64,
    solver: &StepSolver<'_>,
    s: &mut Reduced,
    count: &mut usize,
) -> Option<Step<D>> {
    let StepSolver {
        how,
        blocks,
        coarse,
        tolerance,
    } = *solver;
    if how == StepSolve::ImplicitCg {
        return iterative_step(nm, lambda, blocks, tolerance, count);
    }
    let n = nm.g_c.len();
    let clamp = |d: f64| d.clamp(1e-6, 1e32);
    s.assign(&nm.u);
    for i in 0..n {
        s.add(i, i, lambda * clamp(nm.u.diagonal(i)));
    }
    let mut rhs = nm.g_c.clone();
    let v_inv = damped_inverses(&nm.v, lambda)?;
    schur::eliminate(nm.block_rows(), &v_inv, &nm.g_p, s, &mut rhs);
    let cameras = match how {
        _ if n == 0 => DVector::zeros(0),
        StepSolve::FormedCg => {
            let formed: &Reduced = s;
            let blocks_of_s = blocks
                .iter()
                .map(|cols| {
                    DMatrix::from_fn(cols.len(), cols.len(), |i, j| formed.get(cols[i], cols[j]))
                })
                .collect();
            let preconditioner = BlockJacobi::new(blocks, blocks_of_s);
            let mut scratch = Vec::new();
            let product = |x: &DVector<f64>, y: &mut DVector<f64>| {
                formed.mul_vec_into(x.as_slice(), y.as_mut_slice(), &mut scratch)
            };
            let correction = coarse.and_then(|c| c.correction(formed));
            let precondition = |r: &DVector<f64>, z: &mut DVector<f64>| {
                preconditioner.apply_into(r, z);
                if let Some(c) = &correction {
                    c.add_to(r, z);
                }
            };
            -conjugate_gradients(product, precondition, &rhs, tolerance, count)?
        }
        _ => -s.solve(&rhs)?,
    };
    Some(Step {
        points: back_substitute(nm, &cameras, &v_inv),
        cameras,
    })
}

/// The eliminated blocks' steps from the reduced-side step.
fn back_substitute<const D: usize>(
    nm: &Normal<D>,
    cameras: &DVector<f64>,
    v_inv: &[SMatrix<f64, D, D>],
) -> Vec<SVector<f64, D>> {
    nm.point_obs
        .iter()
        .enumerate()
        .map(|(pi, obs)| {
            let mut acc = nm.g_p[pi];
            for &a in obs {
                let (sa, ca) = nm.obs_cols[a];
                for ra in 0..ca {
                    let d = cameras[nm.cols[sa + ra]];
                    let e = &nm.e[(sa + ra) * D..(sa + ra) * D + D];
                    for c in 0..D {
                        acc[c] += e[c] * d;
                    }
                }
            }
            -(v_inv[pi] * acc)
        })
        .collect()
}

/// The damped step by preconditioned conjugate gradients on `S x = −rhs`, with `S` applied as
/// `(U + λD) x − Σ_b E_b V_b⁻¹ E_bᵀ x` and a block-Jacobi preconditioner made of the diagonal
/// blocks of `U + λD − Σ_a F_a E_aᵀ` (each observation's own contribution).
fn iterative_step<const D: usize>(
    nm: &Normal<D>,
    lambda: f64,
    blocks: &[Vec<usize>],
    tolerance: f64,
    count: &mut usize,
) -> Option<Step<D>> {
    let n = nm.g_c.len();
    let clamp = |d: f64| d.clamp(1e-6, 1e32);
    let v_inv = damped_inverses(&nm.v, lambda)?;
    let damping = DVector::from_fn(n, |i, _| lambda * clamp(nm.u.diagonal(i)));
    let rhs = reduced_rhs(nm, &v_inv);
    let schur = ImplicitSchur {
        nm,
        v_inv: &v_inv,
        damping: &damping,
    };
    let preconditioner = BlockJacobi::new(blocks, diagonal_blocks(&schur, blocks));
    let product = |x: &DVector<f64>, y: &mut DVector<f64>| *y = schur.apply(x);
    let precondition = |r: &DVector<f64>, z: &mut DVector<f64>| preconditioner.apply_into(r, z);
    let x = -conjugate_gradients(product, precondition, &rhs, tolerance, count)?;
    Some(Step {
        points: back_substitute(nm, &x, &v_inv),
        cameras: x,
    })
}

/// Preconditioned conjugate gradients on `S x = rhs` from `x = 0`, `S` applied by `product`
/// (`y = S x`); the step is `−x`. Stops where iteration `i` lowers `Q(x) = ½ xᵀ S x − rhsᵀ x`
/// by less than `eta / i` of `Q(x)` (see [`BundleOptions::linear_tolerance`]; the residual
/// alone says little of the step's quality on an ill-conditioned `S`), at a relative residual
/// of [`PCG_RESIDUAL_FLOOR`], after [`PCG_MAX_ITERATIONS`], or where a search direction finds
/// no positive curvature (then with the iterate so far). `None` when the result is not finite.
fn conjugate_gradients(
    mut product: impl FnMut(&DVector<f64>, &mut DVector<f64>),
    precondition: impl Fn(&DVector<f64>, &mut DVector<f64>),
    rhs: &DVector<f64>,
    eta: f64,
    count: &mut usize,
) -> Option<DVector<f64>> {
    let n = rhs.len();
    let mut x = DVector::zeros(n);
    let b_norm = rhs.norm();
    if b_norm == 0.0 {
        return Some(x);
    }
    let mut r = rhs.clone();
    let mut z = DVector::zeros(n);
    precondition(&r, &mut z);
    let mut p = z.clone();
    let mut q = DVector::zeros(n);
    let mut rz = r.dot(&z);
    let mut iterations = 0;
    let mut q_before = 0.0;
    for _ in 0..PCG_MAX_ITERATIONS.min(10 * n + 10) {
        iterations += 1;
        product(&p, &mut q);
        let pq = p.dot(&q);
        if !(pq > 0.0) {
            break;
        }
        let alpha = rz / pq;
        x.axpy(alpha, &p, 1.0);
        r.axpy(-alpha, &q, 1.0);
        if r.norm() <= PCG_RESIDUAL_FLOOR * b_norm {
            break;
        }
        // Q(x) = ½ xᵀ S x − rhsᵀ x = −½ xᵀ (rhs + r); it falls at every iteration.
        let q_now = -0.5 * (x.dot(rhs) + x.dot(&r));
        if eta > 0.0 && q_now < 0.0 && iterations as f64 * (q_now - q_before) / q_now < eta {
            break;
        }
        q_before = q_now;
        precondition(&r, &mut z);
        let rz_new = r.dot(&z);
        p.axpy(1.0, &z, rz_new / rz);
        rz = rz_new;
    }
    *count += iterations;
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Right-hand side of the reduced system, `g_c − Σ E V⁻¹ g_p`, without forming `S`.
fn reduced_rhs<const D: usize>(nm: &Normal<D>, v_inv: &[SMatrix<f64, D, D>]) -> DVector<f64> {
    let mut rhs = nm.g_c.clone();
    for (pi, obs) in nm.point_obs.iter().enumerate() {
        let vg = v_inv[pi] * nm.g_p[pi];
        for &a in obs {
            let (sa, ca) = nm.obs_cols[a];
            for ra in 0..ca {
                let e = &nm.e[(sa + ra) * D..(sa + ra) * D + D];
                rhs[nm.cols[sa + ra]] -= (0..D).map(|c| e[c] * vg[c]).sum::<f64>();
            }
        }
    }
    rhs
}

/// The damped reduced system `S = U + λD − E V⁻¹ Eᵀ` of the iterative path, applied through
/// its factors instead of formed.
struct ImplicitSchur<'a, const D: usize> {
    nm: &'a Normal<D>,
    v_inv: &'a [SMatrix<f64, D, D>],
    /// `λ · clamp(diag U)`.
    damping: &'a DVector<f64>,
}

impl<const D: usize> ImplicitSchur<'_, D> {
    /// `S x`: `(U + λD) x`, less `E_b V_b⁻¹ E_bᵀ x` for each eliminated block `b`.
    fn apply(&self, x: &DVector<f64>) -> DVector<f64> {
        let nm = self.nm;
        let mut y = nm.u.mul_vec(x) + self.damping.component_mul(x);
        for (pi, obs) in nm.point_obs.iter().enumerate() {
            let mut t = SVector::<f64, D>::zeros();
            for &a in obs {
                let (sa, ca) = nm.obs_cols[a];
                for ra in 0..ca {
                    let xv = x[nm.cols[sa + ra]];
                    let e = &nm.e[(sa + ra) * D..(sa + ra) * D + D];
                    for c in 0..D {
                        t[c] += e[c] * xv;
                    }
                }
            }
            let w = self.v_inv[pi] * t;
            for &a in obs {
                let (sa, ca) = nm.obs_cols[a];
                for ra in 0..ca {
                    let e = &nm.e[(sa + ra) * D..(sa + ra) * D + D];
                    y[nm.cols[sa + ra]] -= (0..D).map(|c| e[c] * w[c]).sum::<f64>();
                }
            }
        }
        y
    }
}

/// The block-Jacobi preconditioner of the iterative path: the inverse of each parameter block's
/// diagonal block of `S` (from each observation's own contribution to it).
struct BlockJacobi<'a> {
    blocks: &'a [Vec<usize>],
    inverses: Vec<DMatrix<f64>>,
}

impl<'a> BlockJacobi<'a> {
    /// Inverts the diagonal blocks `matrices` of `S` over `blocks` (column lists); a block
    /// that is not positive definite is preconditioned by its diagonal alone.
    fn new(blocks: &'a [Vec<usize>], matrices: Vec<DMatrix<f64>>) -> Self {
        let inverses = matrices
            .into_iter()
            .map(|b| {
                let d = b.diagonal();
                match b.cholesky() {
                    Some(c) => c.inverse(),
                    None => DMatrix::from_diagonal(&d.map(|v| if v > 0.0 { 1.0 / v } else { 1.0 })),
                }
            })
            .collect();
        BlockJacobi { blocks, inverses }
    }

    /// `z = M⁻¹ r`, block by block.
    fn apply_into(&self, r: &DVector<f64>, z: &mut DVector<f64>) {
        for (cols, inverse) in self.blocks.iter().zip(&self.inverses) {
            for (i, &ci) in cols.iter().enumerate() {
                z[ci] = cols
                    .iter()
                    .enumerate()
                    .map(|(j, &cj)| inverse[(i, j)] * r[cj])
                    .sum();
            }
        }
    }
}

/// The diagonal blocks of `S` over `blocks`: those of `U + λD`, less each observation's
/// `F_a E_aᵀ` (`F_a = E_a V⁻¹`) where both of its columns fall in the same block.
fn diagonal_blocks<const D: usize>(
    schur: &ImplicitSchur<'_, D>,
    blocks: &[Vec<usize>],
) -> Vec<nalgebra::DMatrix<f64>> {
    let (nm, v_inv, damping) = (schur.nm, schur.v_inv, schur.damping);
    // Block and position within the block of every reduced-side column.
    let mut block_of = vec![(0usize, 0usize); nm.g_c.len()];
    for (k, cols) in blocks.iter().enumerate() {
        for (q, &c) in cols.iter().enumerate() {
            block_of[c] = (k, q);
        }
    }
    let mut m: Vec<nalgebra::DMatrix<f64>> = blocks
        .iter()
        .map(|cols| {
            nalgebra::DMatrix::from_fn(cols.len(), cols.len(), |i, j| {
                nm.u.get(cols[i], cols[j]) + if i == j { damping[cols[i]] } else { 0.0 }
            })
        })
        .collect();
    for (pi, obs) in nm.point_obs.iter().enumerate() {
        for &a in obs {
            let (sa, ca) = nm.obs_cols[a];
            for ra in 0..ca {
                let ea = &nm.e[(sa + ra) * D..(sa + ra) * D + D];
                let fa = SVector::<f64, D>::from_fn(|c, _| {
                    (0..D).map(|k| ea[k] * v_inv[pi][(k, c)]).sum()
                });
                let col_a = nm.cols[sa + ra];
                for rb in 0..ca {
                    let col_b = nm.cols[sa + rb];
                    let ((ka, qa), (kb, qb)) = (block_of[col_a], block_of[col_b]);
                    if ka != kb {
                        continue;
                    }
                    let eb = &nm.e[(sa + rb) * D..(sa + rb) * D + D];
                    let v: f64 = (0..D).map(|c| fa[c] * eb[c]).sum();
                    m[ka][(qa, qb)] -= v;
                }
            }
        }
    }
    m
}

/// Default [`BundleOptions::linear_tolerance`], Ceres's default `eta` for its iterative
/// linear solvers.
pub const PCG_FORCING: f64 = 0.1;

/// Relative residual at which the conjugate gradients stop whatever the forcing test says.
pub const PCG_RESIDUAL_FLOOR: f64 = 1e-6;

/// Most conjugate-gradient iterations per trial step.
const PCG_MAX_ITERATIONS: usize = 1000;

/// Moves `p` by `step` in place; `false` when the step gives invalid intrinsics (e.g. f ≤ 0),
/// which rejects it (the damping then grows). `p` is then partly moved: the caller puts back
/// what it kept ([`Parameters`]).
fn apply_step<const D: usize>(p: &mut BundleProblem, layout: &Layout, step: &Step<D>) -> bool {
    for (i, im) in p.images.iter_mut().enumerate() {
        let d = if let Some(off) = layout.pose_offset[i] {
            Vector6::from_iterator((0..6).map(|c| step.cameras[off + c]))
        } else if let Some(bi) = layout.pose_index[i] {
            Vector6::from_iterator((0..6).map(|c| step.points[bi][c]))
        } else {
            continue;
        };
        im.pose = im.pose.retract(&d);
    }
    for (g, group) in p.groups.iter_mut().enumerate() {
        if let Some(off) = layout.group_offset[g] {
            let mut params = [0.0; MAX_INTRINSICS];
            let n = group.camera.num_params();
            group.camera.params(&mut params[..n]);
            for (q, &k) in layout.group_free[g].iter().enumerate() {
                params[k] += step.cameras[off + q];
            }
            if group.camera.set_params(&params[..n]).is_err() {
                return false;
            }
        }
    }
    for (o, offset) in p.prior_offsets.iter_mut().enumerate() {
        if let Some(bo) = layout.bias_offset[o] {
            offset.value +=
                Vector3::new(step.cameras[bo], step.cameras[bo + 1], step.cameras[bo + 2]);
        }
    }
    for (j, pt) in p.points.iter_mut().enumerate() {
        if let Some(pi) = layout.point_index[j] {
            pt.position += Vector3::new(step.points[pi][0], step.points[pi][1], step.points[pi][2]);
        } else if let Some(off) = layout.point_offset[j] {
            pt.position += Vector3::new(
                step.cameras[off],
                step.cameras[off + 1],
                step.cameras[off + 2],
            );
        }
    }
    true
}

/// The values a step changes (poses, intrinsics, offsets, points), kept so that a rejected step
/// is undone by putting them back. A trial step on a copy of the problem would copy its
/// observations too, the largest part of a block of hundreds of images, at every iteration.
#[derive(Default)]
struct Parameters {
    poses: Vec<timesift_core::Pose>,
    cameras: Vec<timesift_core::Camera>,
    offsets: Vec<Vector3<f64>>,
    points: Vec<Vector3<f64>>,
}

impl Parameters {
    /// Keeps `p`'s values, reusing the storage of the last call.
    fn keep(&mut self, p: &BundleProblem) {
        self.poses.clear();
        self.poses.extend(p.images.iter().map(|im| im.pose));
        self.cameras.clear();
        self.cameras
            .extend(p.groups.iter().map(|g| g.camera.clone()));
        self.offsets.clear();
        self.offsets.extend(p.prior_offsets.iter().map(|o| o.value));
        self.points.clear();
        self.points.extend(p.points.iter().map(|pt| pt.position));
    }

    /// Puts the kept values back into `p` (the problem they were kept from).
    fn put_back(&self, p: &mut BundleProblem) {
        for (im, pose) in p.images.iter_mut().zip(&self.poses) {
            im.pose = *pose;
        }
        for (g, camera) in p.groups.iter_mut().zip(&self.cameras) {
            g.camera.clone_from(camera);
        }
        for (o, value) in p.prior_offsets.iter_mut().zip(&self.offsets) {
            o.value = *value;
        }
        for (pt, position) in p.points.iter_mut().zip(&self.points) {
            pt.position = *position;
        }
    }
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
    for o in &p.prior_offsets {
        s += o.value.norm_squared();
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

/// How each damped step solves the reduced system.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum StepSolve {
    /// Cholesky of the formed `S` (dense or sparse storage).
    Factor,
    /// Conjugate gradients on the formed (sparse) `S`, preconditioned by its block diagonal
    /// and the coarse level of [`CoarseSpace`] (when the reduced side holds the poses).
    FormedCg,
    /// Conjugate gradients through the eliminated blocks, `S` never formed.
    ImplicitCg,
}

/// Camera-side parameters from which [`LinearSolver::Auto`] solves a reduced system denser
/// than [`ITERATIVE_DENSITY`] by conjugate gradients rather than by Cholesky.
/// Why: epochs flown over the same ground tie every image to the images of every other epoch
/// there, so `S` of a multi-epoch block has a share of non-zeros that stays about constant as
/// the block grows and its Cholesky factor fills in to nearly dense: its cost grows with the
/// cube of the images. A product with the formed `S` costs its non-zeros, and the conjugate
/// gradients need some tens to hundreds of them per step (scale bench: the factorisation was
/// most of the align stage at 1,600 images, 9,600 parameters).
pub const ITERATIVE_FROM: usize = DENSE_FILL_LIMIT + 1;

/// Share of the reduced system's lower triangle that is non-zero above which
/// [`LinearSolver::Auto`] expects its Cholesky factor to fill in (see [`ITERATIVE_FROM`]).
pub const ITERATIVE_DENSITY: f64 = 0.05;

/// Empty storage of the reduced system for the chosen solver, and how steps solve it; the
/// sparse pattern couples the columns of each observation and of all observations of each
/// eliminated block. `factorise`: the caller needs the Cholesky factor (covariances), so
/// [`LinearSolver::Auto`] never picks conjugate gradients.
fn reduced_storage(
    p: &BundleProblem,
    layout: &Layout,
    solver: LinearSolver,
    factorise: bool,
) -> Result<(Reduced, StepSolve), BundleError> {
    let n = layout.num_camera_params;
    let implicit = solver == LinearSolver::IterativeSchur;
    let sparse = match solver {
        LinearSolver::DenseSchur => false,
        LinearSolver::SparseSchur
        | LinearSolver::IterativeSchur
        | LinearSolver::SparseIterativeSchur => true,
        LinearSolver::Auto => n > DENSE_LIMIT,
    };
    if !sparse || n == 0 {
        return Ok((Reduced::dense(n), StepSolve::Factor));
    }
    let mut groups: Vec<Vec<usize>> = Vec::new();
    let mut per_block: Vec<Vec<usize>> = vec![Vec::new(); layout.num_free_points];
    for o in &p.observations {
        let cols = layout.observation_columns(p, o.image, o.point);
        match layout.eliminated(o.image, o.point) {
            // Its block's set holds these columns (the elimination couples all of them).
            Some(bi) if !implicit => per_block[bi].extend_from_slice(&cols),
            _ => groups.push(cols),
        }
    }
    for c in &p.center_priors {
        let mut cols: Vec<usize> =
            layout.pose_offset[c.image].map_or(Vec::new(), |off| (off..off + 6).collect());
        if let Some(bo) = c.offset.and_then(|o| layout.bias_offset[o]) {
            cols.extend(bo..bo + 3);
        }
        if !cols.is_empty() {
            groups.push(cols);
        }
    }
    for bar in &p.scale_bars {
        let cols: Vec<usize> = [layout.point_offset[bar.a], layout.point_offset[bar.b]]
            .into_iter()
            .flatten()
            .flat_map(|o| o..o + 3)
            .collect();
        groups.push(cols);
    }
    // The implicit solver never forms S: U's pattern (observations, priors, bars) is enough.
    if !implicit {
        for mut cols in per_block {
            cols.sort_unstable();
            cols.dedup();
            groups.push(cols);
        }
    }
    let analysis_failed =
        || BundleError::InvalidProblem("symbolic analysis of the reduced system failed".into());
    let pattern = SparsePattern::new(n, &groups, false).ok_or_else(analysis_failed)?;
    // Few eliminated blocks seen by many reduced-side blocks make `S` nearly full: then dense
    // storage (direct indexing, dense Cholesky) beats sparse, up to a size where n² stays
    // modest; beyond it, a dense-ish S is solved iteratively.
    let density = pattern.nnz_lower() as f64 / (0.5 * n as f64 * (n + 1) as f64);
    let how = match solver {
        LinearSolver::IterativeSchur => StepSolve::ImplicitCg,
        LinearSolver::SparseIterativeSchur => StepSolve::FormedCg,
        LinearSolver::Auto if !factorise && n >= ITERATIVE_FROM && density > ITERATIVE_DENSITY => {
            StepSolve::FormedCg
        }
        LinearSolver::Auto if density > 0.25 && n <= DENSE_FILL_LIMIT => {
            return Ok((Reduced::dense(n), StepSolve::Factor));
        }
        _ => StepSolve::Factor,
    };
    let pattern = match how {
        StepSolve::Factor => pattern.analysed().ok_or_else(analysis_failed)?,
        _ => pattern,
    };
    Ok((Reduced::sparse(pattern), how))
}

/// Adjusts the problem in place and reports what happened. Points are eliminated, or the poses
/// when that leaves the smaller reduced system (many cameras, few points).
pub fn solve(
    problem: &mut BundleProblem,
    options: &BundleOptions,
) -> Result<BundleReport, BundleError> {
    problem.validate()?;
    options.loss.validate()?;
    if !(0.0..1.0).contains(&options.linear_tolerance) {
        return Err(BundleError::InvalidProblem(format!(
            "linear_tolerance {}: expected at least 0 and below 1",
            options.linear_tolerance
        )));
    }
    let by_points = Layout::with(problem, Eliminate::Points);
    if by_points.num_camera_params == 0 && by_points.num_free_points == 0 {
        return Err(BundleError::NothingToAdjust);
    }
    let by_poses = Layout::with(problem, Eliminate::Poses);
    // A free offset couples the centre priors of many poses; the eliminated blocks must stay
    // independent, so with one the points are eliminated whatever was asked.
    let coupled_poses = by_points.bias_offset.iter().any(Option::is_some);
    let poses = !coupled_poses
        && match options.elimination {
            Elimination::Auto => by_poses.num_camera_params < by_points.num_camera_params,
            Elimination::Points => false,
            Elimination::Poses => true,
        };
    if poses {
        run::<6>(problem, &by_poses, options)
    } else {
        run::<3>(problem, &by_points, options)
    }
}

fn run<const D: usize>(
    problem: &mut BundleProblem,
    layout: &Layout,
    options: &BundleOptions,
) -> Result<BundleReport, BundleError> {
    let initial_cost = cost_of(problem, &options.loss);
    let mut cost = initial_cost;
    let mut radius = options.initial_trust_region_radius;
    let mut nu = 2.0;
    let mut iterations = 0;
    let mut successful_steps = 0;
    let mut termination = Termination::MaxIterations;
    let mut linear_iterations = 0;
    let (storage, how) = reduced_storage(problem, layout, options.linear_solver, false)?;
    let blocks = match how {
        StepSolve::Factor => Vec::new(),
        _ => layout.parameter_blocks(problem),
    };
    let coarse = match how {
        StepSolve::FormedCg => CoarseSpace::new(problem, layout),
        _ => None,
    };
    let solver = StepSolver {
        how,
        blocks: &blocks,
        coarse: coarse.as_ref(),
        tolerance: options.linear_tolerance,
    };
    let mut nm = linearize::<D>(problem, layout, &options.loss, &storage);
    // The accepted parameters, to put back when a trial step is rejected.
    let mut kept = Parameters::default();
    kept.keep(problem);
    let mut reduced = storage;
    while iterations < options.max_iterations {
        iterations += 1;
        if max_gradient(&nm) <= options.gradient_tolerance {
            termination = Termination::GradientTolerance;
            break;
        }
        let lambda = 1.0 / radius;
        let Some(step) = damped_step(&nm, lambda, &solver, &mut reduced, &mut linear_iterations)
        else {
            radius /= nu;
            nu *= 2.0;
            if radius < 1e-32 {
                termination = Termination::NoProgress;
                break;
            }
            continue;
        };
        let (model, step_sq) = predicted_decrease(&nm, &step, lambda);
        let x_norm = parameter_norm(problem);
        if step_sq.sqrt() <= options.parameter_tolerance * (x_norm + options.parameter_tolerance) {
            termination = Termination::ParameterTolerance;
            break;
        }
        // A step that gives invalid intrinsics is rejected like one that does not decrease
        // the cost.
        let new_cost = if apply_step(problem, layout, &step) {
            cost_of(problem, &options.loss)
        } else {
            f64::INFINITY
        };
        let rho = (cost - new_cost) / model.max(f64::MIN_POSITIVE);
        if new_cost.is_finite() && new_cost < cost && rho > 1e-3 {
            let decrease = (cost - new_cost) / cost;
            cost = new_cost;
            successful_steps += 1;
            radius /= (1.0f64 / 3.0).max(1.0 - (2.0 * rho - 1.0).powi(3));
            radius = radius.min(1e16);
            nu = 2.0;
            if decrease <= options.function_tolerance {
                termination = Termination::FunctionTolerance;
                break;
            }
            nm.relinearize(problem, layout, &options.loss);
            kept.keep(problem);
        } else {
            kept.put_back(problem);
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
        linear_iterations,
    })
}

/// The largest absolute gradient component, reduced side and eliminated blocks alike (the
/// gradient-tolerance test).
fn max_gradient<const D: usize>(nm: &Normal<D>) -> f64 {
    nm.g_c
        .iter()
        .chain(nm.g_p.iter().flat_map(|g| g.iter()))
        .fold(0.0f64, |m, v| m.max(v.abs()))
}

/// Predicted decrease of the linear model, `½ (λ δᵀDδ − gᵀδ)` (`D` the clamped diagonal), and
/// the squared norm of the step `δ` (the parameter-tolerance test).
fn predicted_decrease<const D: usize>(nm: &Normal<D>, step: &Step<D>, lambda: f64) -> (f64, f64) {
    let clamp = |d: f64| d.clamp(1e-6, 1e32);
    let mut model = 0.0;
    for i in 0..step.cameras.len() {
        let d = step.cameras[i];
        model += lambda * clamp(nm.u.diagonal(i)) * d * d - nm.g_c[i] * d;
    }
    let mut step_sq = step.cameras.norm_squared();
    for (pi, d) in step.points.iter().enumerate() {
        for c in 0..D {
            model += lambda * clamp(nm.v[pi][(c, c)]) * d[c] * d[c] - nm.g_p[pi][c] * d[c];
        }
        step_sq += d.norm_squared();
    }
    model *= 0.5;
    (model, step_sq)
}

/// Number of adjusted parameters in the local (update) coordinates used by [`gradient`] and
/// [`perturbed`]: free poses (6 each), free intrinsics, free prior offsets (3 each), free points
/// on scale bars (3 each), then the other free points (3 each).
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
    let nm = linearize::<3>(problem, &layout, loss, &storage);
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
    let step = Step::<3> {
        cameras: DVector::from_iterator(n, delta[..n].iter().copied()),
        points: delta[n..]
            .chunks(3)
            .map(|c| SVector::<f64, 3>::new(c[0], c[1], c[2]))
            .collect(),
    };
    let mut moved = problem.clone();
    apply_step(&mut moved, &layout, &step).then_some(moved)
}

#[cfg(test)]
mod tests {
    use nalgebra::{Vector2, Vector3};
    use timesift_core::{BrownCamera, Camera, Pose, SeededRng, project_world};

    use super::*;
    use crate::problem::{BundleImage, BundlePoint, CameraGroup, Observation};

    /// Six views on a ring around 60 points, self-calibrating f and k1, observations noisy.
    fn ring(seed: u64) -> BundleProblem {
        let mut rng = SeededRng::new(seed);
        let cam = BrownCamera::new(1600, 1200, 1500.0).unwrap();
        let points: Vec<Vector3<f64>> = (0..60)
            .map(|_| {
                Vector3::new(
                    rng.uniform_range(-8.0, 8.0),
                    rng.uniform_range(-8.0, 8.0),
                    rng.uniform_range(-2.0, 2.0),
                )
            })
            .collect();
        let poses: Vec<Pose> = (0..6)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / 6.0;
                Pose::look_at(
                    &Vector3::new(30.0 * a.cos(), 30.0 * a.sin(), 20.0),
                    &Vector3::zeros(),
                )
                .unwrap()
            })
            .collect();
        let mut observations = Vec::new();
        for (image, pose) in poses.iter().enumerate() {
            for (point, x) in points.iter().enumerate() {
                if let Ok(px) = project_world(&cam, pose, x) {
                    observations.push(Observation {
                        image,
                        point,
                        pixel: px + Vector2::new(rng.normal(), rng.normal()),
                        sigma_px: 1.0,
                    });
                }
            }
        }
        BundleProblem {
            groups: vec![CameraGroup::with_free(Camera::Brown(cam), &["f", "k1"]).unwrap()],
            images: poses
                .into_iter()
                .map(|pose| BundleImage {
                    pose,
                    group: 0,
                    fixed: false,
                })
                .collect(),
            points: points
                .into_iter()
                .map(|position| BundlePoint {
                    position,
                    fixed: false,
                })
                .collect(),
            observations,
            ..BundleProblem::default()
        }
    }

    /// The values a linearisation holds, as bits.
    fn bits(nm: &Normal<3>) -> Vec<u64> {
        let n = nm.g_c.len();
        let u = (0..n).flat_map(|i| (0..=i).map(move |j| (i, j)));
        u.map(|(i, j)| nm.u.get(i, j))
            .chain(nm.g_c.iter().copied())
            .chain(nm.v.iter().flat_map(|m| m.iter().copied()))
            .chain(nm.g_p.iter().flat_map(|g| g.iter().copied()))
            .chain(nm.e.iter().copied())
            .chain(std::iter::once(nm.cost))
            .map(f64::to_bits)
            .chain(nm.cols.iter().map(|&c| c as u64))
            .chain(nm.point_obs.iter().flatten().map(|&o| o as u64))
            .collect()
    }

    /// Observations linearised in parallel batches are summed as a serial pass sums them: the
    /// same bits on any number of threads, over more than one batch, in sparse storage.
    #[test]
    fn a_linearisation_gives_the_same_bits_on_any_number_of_threads() {
        let mut p = views_on_a_ring(100, 1000, 20);
        assert!(p.observations.len() > LINEARISE_BATCH);
        let mut rng = SeededRng::new(4);
        for o in &mut p.observations {
            o.pixel += Vector2::new(rng.normal(), rng.normal()) * 0.5;
        }
        let layout = Layout::new(&p);
        let (storage, _) = reduced_storage(&p, &layout, LinearSolver::SparseSchur, false).unwrap();
        let on = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| bits(&linearize::<3>(&p, &layout, &Loss::Huber(1.0), &storage)))
        };
        let serial = on(1);
        for threads in [2, 3] {
            assert!(on(threads) == serial, "{threads} threads");
        }
    }

    #[test]
    fn a_linearisation_redone_in_place_equals_a_fresh_one() {
        let start = ring(3);
        let layout = Layout::with(&start, Eliminate::Points);
        let delta: Vec<f64> = (0..num_parameters(&start))
            .map(|k| 1e-3 * ((k * 7919) % 13) as f64)
            .collect();
        let moved = perturbed(&start, &delta).unwrap();
        for solver in [LinearSolver::DenseSchur, LinearSolver::SparseSchur] {
            let (storage, how) = reduced_storage(&start, &layout, solver, false).unwrap();
            for loss in [Loss::Trivial, Loss::Huber(1.5)] {
                let mut nm = linearize::<3>(&start, &layout, &loss, &storage);
                let _ = nm.block_rows();
                nm.relinearize(&moved, &layout, &loss);
                let fresh = linearize::<3>(&moved, &layout, &loss, &storage);
                assert!(bits(&nm) == bits(&fresh), "{solver:?} {loss:?}");
                assert_ne!(
                    bits(&fresh),
                    bits(&linearize::<3>(&start, &layout, &loss, &storage))
                );
                // The block rows kept (refilled) give the step fresh ones give.
                assert!(nm.rows.get().is_some());
                let step = |nm: &Normal<3>| {
                    let solver = StepSolver {
                        how,
                        blocks: &[],
                        coarse: None,
                        tolerance: 0.0,
                    };
                    let s = damped_step(nm, 1e-3, &solver, &mut storage.clone(), &mut 0).unwrap();
                    let points = s.points.iter().flat_map(|p| p.iter().copied());
                    s.cameras
                        .iter()
                        .copied()
                        .chain(points)
                        .map(f64::to_bits)
                        .collect::<Vec<_>>()
                };
                assert!(step(&nm) == step(&fresh), "{solver:?} {loss:?}");
            }
        }
    }

    /// `images` views on a ring about the scene of [`ring`], point `j` seen by the `seen_by`
    /// views from view `j · images / points` on: every view tied to about `2 · seen_by`
    /// others, as a view of a multi-epoch block is to the views of every epoch over its ground.
    fn views_on_a_ring(images: usize, points: usize, seen_by: usize) -> BundleProblem {
        let mut rng = SeededRng::new(3);
        let cam = BrownCamera::new(1600, 1200, 1500.0).unwrap();
        let images: Vec<BundleImage> = (0..images)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / images as f64;
                BundleImage {
                    pose: Pose::look_at(
                        &Vector3::new(30.0 * a.cos(), 30.0 * a.sin(), 20.0),
                        &Vector3::zeros(),
                    )
                    .unwrap(),
                    group: 0,
                    fixed: k == 0,
                }
            })
            .collect();
        let points: Vec<BundlePoint> = (0..points)
            .map(|_| BundlePoint {
                position: Vector3::new(
                    rng.uniform_range(-3.0, 3.0),
                    rng.uniform_range(-3.0, 3.0),
                    rng.uniform_range(-1.0, 1.0),
                ),
                fixed: false,
            })
            .collect();
        let mut observations = Vec::new();
        for (point, pt) in points.iter().enumerate() {
            let first = point * images.len() / points.len();
            for k in first..first + seen_by {
                let image = k % images.len();
                if let Ok(pixel) = project_world(&cam, &images[image].pose, &pt.position) {
                    observations.push(Observation {
                        image,
                        point,
                        pixel,
                        sigma_px: 1.0,
                    });
                }
            }
        }
        BundleProblem {
            groups: vec![CameraGroup::with_free(Camera::Brown(cam), &["f", "k1"]).unwrap()],
            images,
            points,
            observations,
            ..BundleProblem::default()
        }
    }

    /// Auto solves a large reduced system with a large share of non-zeros by conjugate
    /// gradients on the formed system (its Cholesky factor would fill in), but factorises it
    /// when the caller needs the factor (covariances); a small or sparse one it factorises.
    #[test]
    fn auto_iterates_on_large_filled_systems_and_factorises_when_asked() {
        let images = ITERATIVE_FROM / 6 + 1;
        let big = views_on_a_ring(images, images, images / 12);
        let layout = Layout::new(&big);
        assert!(layout.num_camera_params >= ITERATIVE_FROM);
        let (_, how) = reduced_storage(&big, &layout, LinearSolver::Auto, false).unwrap();
        assert_eq!(how, StepSolve::FormedCg);
        let (mut s, how) = reduced_storage(&big, &layout, LinearSolver::Auto, true).unwrap();
        assert_eq!(how, StepSolve::Factor);
        for i in 0..layout.num_camera_params {
            s.add(i, i, 1.0);
        }
        assert!(
            s.factor().is_some(),
            "the storage for covariances factorises"
        );
        // As many views, each tied to a few neighbours only: a sparse factor stays sparse.
        let banded = views_on_a_ring(images, images, 4);
        let layout = Layout::new(&banded);
        let (_, how) = reduced_storage(&banded, &layout, LinearSolver::Auto, false).unwrap();
        assert_eq!(how, StepSolve::Factor);
        let small = views_on_a_ring(40, 40, 10);
        let layout = Layout::new(&small);
        let (_, how) = reduced_storage(&small, &layout, LinearSolver::Auto, false).unwrap();
        assert_eq!(how, StepSolve::Factor);
    }

    /// On a block of views each tied to a sixth of the others, noisy observations and free
    /// intrinsics, the conjugate gradients preconditioned with and without the coarse level
    /// reach the minimum the Cholesky factor reaches, and the coarse level needs fewer
    /// products.
    #[test]
    fn the_coarse_level_reaches_the_factors_minimum_in_fewer_products() {
        let mut start = views_on_a_ring(120, 240, 20);
        let mut rng = SeededRng::new(9);
        for o in &mut start.observations {
            o.pixel += Vector2::new(rng.normal(), rng.normal()) * 0.5;
        }
        let solved_to = |solver: LinearSolver, coarse: bool, tolerance: f64| {
            let mut p = start.clone();
            let layout = Layout::new(&p);
            let (storage, how) = reduced_storage(&p, &layout, solver, false).unwrap();
            let blocks = layout.parameter_blocks(&p);
            let space = coarse.then(|| CoarseSpace::new(&p, &layout).unwrap());
            let nm = linearize::<3>(&p, &layout, &Loss::Trivial, &storage);
            let mut count = 0;
            let solver = StepSolver {
                how,
                blocks: &blocks,
                coarse: space.as_ref(),
                tolerance,
            };
            let step = damped_step(&nm, 1e-4, &solver, &mut storage.clone(), &mut count).unwrap();
            assert!(apply_step(&mut p, &layout, &step));
            (cost(&p, &Loss::Trivial), count)
        };
        let solved = |solver, coarse| solved_to(solver, coarse, 0.0);
        let (direct, _) = solved(LinearSolver::SparseSchur, false);
        let (jacobi, plain) = solved(LinearSolver::SparseIterativeSchur, false);
        let (two_level, fewer) = solved(LinearSolver::SparseIterativeSchur, true);
        let (forced, fewest) = solved_to(LinearSolver::SparseIterativeSchur, true, PCG_FORCING);
        println!(
            "Cholesky {direct}, block Jacobi {jacobi} in {plain}, coarse {two_level} in {fewer}, \
             forced {forced} in {fewest}"
        );
        // The forcing test stops the step early, where it has most of the exact step's decrease.
        let start_cost = cost(&start, &Loss::Trivial);
        assert!(
            fewest < fewer && start_cost - forced > 0.9 * (start_cost - direct),
            "{fewest} products for {forced}, {fewer} for {two_level}, from {start_cost}"
        );
        assert!(direct < cost(&start, &Loss::Trivial));
        for c in [jacobi, two_level] {
            assert!((c / direct - 1.0).abs() < 1e-6, "{c} against {direct}");
        }
        assert!(
            fewer < plain,
            "{fewer} products with the coarse level, {plain} without"
        );
    }

    /// On a noisy self-calibrating ring, every linear solver reaches the same minimum: the
    /// conjugate gradients' steps are inexact, not different.
    #[test]
    fn every_linear_solver_reaches_the_same_minimum() {
        let mut finals = Vec::new();
        for solver in [
            LinearSolver::DenseSchur,
            LinearSolver::SparseSchur,
            LinearSolver::IterativeSchur,
            LinearSolver::SparseIterativeSchur,
        ] {
            let mut p = ring(21);
            p.images[0].fixed = true;
            let options = BundleOptions {
                linear_solver: solver,
                ..BundleOptions::default()
            };
            let report = solve(&mut p, &options).unwrap();
            let iterative = matches!(
                solver,
                LinearSolver::IterativeSchur | LinearSolver::SparseIterativeSchur
            );
            assert_eq!(report.linear_iterations > 0, iterative, "{solver:?}");
            finals.push(report.final_cost);
        }
        for cost in &finals[1..] {
            assert!((cost / finals[0] - 1.0).abs() < 1e-6, "{finals:?}");
        }
        assert!(finals[0] < cost(&ring(21), &Loss::Trivial));
    }

    /// A step applied in place and put back leaves the problem as it was, bit for bit, and one
    /// that makes the focal length negative is refused.
    #[test]
    fn a_step_put_back_leaves_the_problem_as_it_was() {
        let start = ring(11);
        let layout = Layout::new(&start);
        let n = layout.num_camera_params;
        let step = Step::<3> {
            cameras: DVector::from_fn(n, |k, _| 1e-2 * ((k * 31) % 7) as f64),
            points: vec![SVector::<f64, 3>::new(0.1, -0.2, 0.3); start.points.len()],
        };
        let mut kept = Parameters::default();
        let mut p = start.clone();
        kept.keep(&p);
        assert!(apply_step(&mut p, &layout, &step));
        assert_ne!(p, start);
        kept.put_back(&mut p);
        assert_eq!(p, start);
        let f = layout.group_offset[0].unwrap();
        let mut bad = Step::<3> {
            cameras: DVector::zeros(n),
            points: step.points.clone(),
        };
        bad.cameras[f] = -1e4;
        assert!(!apply_step(&mut p, &layout, &bad));
        kept.put_back(&mut p);
        assert_eq!(p, start);
    }
}
