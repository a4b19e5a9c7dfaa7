//! Point-to-plane ICP (Chen & Medioni 1992) with trimming (Chetverikov et al. 2002), rigid or with
//! scale, for registering one epoch's cloud onto another's on stable ground.
//!
//! The caller passes only stable points (see [`select`]); the target's normals come from PCA of its
//! `normal_neighbours` nearest points. Each iteration pairs every source point with its nearest
//! target point, drops pairs farther than `max_distance` and keeps the `overlap` fraction with the
//! smallest distances, then solves the linearised point-to-plane least squares for a small rotation,
//! translation (and scale). Coordinates are centred on the target's centroid throughout, so UTM
//! magnitudes do not cost precision.

use nalgebra::{Matrix3, Rotation3, SMatrix, SVector, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::ChangeError;
use crate::cloud::{PointIndex, fit_plane};
use crate::error::positive;

/// What the transform may do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum IcpModel {
    /// Rotation and translation.
    Rigid,
    /// Rotation, translation and one scale factor.
    Similarity,
}

/// ICP options.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IcpOptions {
    /// Rigid or similarity.
    pub model: IcpModel,
    /// Iteration limit.
    pub max_iterations: usize,
    /// Pairs farther apart than this (m) are not used.
    pub max_distance: f64,
    /// Fraction of the remaining pairs kept, smallest distances first (trimmed ICP), in (0, 1].
    pub overlap: f64,
    /// Neighbours for the target normals.
    pub normal_neighbours: usize,
    /// Stop when the update's rotation (rad) and translation (m) are below these.
    pub tolerance_rotation: f64,
    /// Translation tolerance, m.
    pub tolerance_translation: f64,
}

impl Default for IcpOptions {
    fn default() -> Self {
        IcpOptions {
            model: IcpModel::Rigid,
            max_iterations: 100,
            max_distance: 5.0,
            overlap: 0.9,
            normal_neighbours: 12,
            tolerance_rotation: 1e-10,
            tolerance_translation: 1e-8,
        }
    }
}

/// The estimated transform `target = scale · R · source + translation` and its fit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IcpResult {
    /// Rotation, row-major.
    pub rotation: [[f64; 3]; 3],
    /// Translation in the clouds' frame, m.
    pub translation: [f64; 3],
    /// Scale (1 for the rigid model).
    pub scale: f64,
    /// Rotation angle, degrees.
    pub rotation_deg: f64,
    /// Iterations run.
    pub iterations: usize,
    /// Whether the update fell below the tolerances.
    pub converged: bool,
    /// Pairs used in the last iteration.
    pub pairs: usize,
    /// RMS point-to-plane distance of those pairs after the last update, m.
    pub rms: f64,
}

impl IcpResult {
    /// Applies the transform to a point.
    pub fn transform(&self, p: &[f64; 3]) -> [f64; 3] {
        let r = Matrix3::from_row_slice(&self.rotation.concat());
        let q = self.scale * (r * Vector3::from(*p)) + Vector3::from(self.translation);
        [q.x, q.y, q.z]
    }
}

/// The points whose flag is set.
pub fn select(points: &[[f64; 3]], keep: &[bool]) -> Vec<[f64; 3]> {
    points
        .iter()
        .zip(keep)
        .filter(|(_, k)| **k)
        .map(|(p, _)| *p)
        .collect()
}

/// Registers `source` onto `target`.
pub fn icp(
    source: &[[f64; 3]],
    target: &[[f64; 3]],
    options: &IcpOptions,
) -> Result<IcpResult, ChangeError> {
    let unknowns = check_input(source, target, options)?;
    let index = PointIndex::new(target)?;
    let centre = target
        .iter()
        .fold(Vector3::zeros(), |s, p| s + Vector3::from(*p))
        / target.len() as f64;
    let normals = target_normals(target, &index, options.normal_neighbours);
    let frame = IcpFrame {
        target,
        index: &index,
        normals,
        centre,
        source_c: source.iter().map(|p| Vector3::from(*p) - centre).collect(),
    };

    // Current transform in centred coordinates: y = s R x + t.
    let mut current = Transform {
        rotation: Matrix3::identity(),
        translation: Vector3::zeros(),
        scale: 1.0,
    };
    let mut converged = false;
    let mut iterations = 0;
    let mut pairs_used = 0;
    let mut rms = f64::NAN;
    let max_d2 = options.max_distance * options.max_distance;
    let mut pairs: Vec<(f64, usize, u32)> = Vec::with_capacity(source.len());
    for _ in 0..options.max_iterations {
        iterations += 1;
        frame.trimmed_pairs(&current, max_d2, options, unknowns, &mut pairs)?;
        let (ata, atb) = frame.normal_equations(&current, &pairs);
        let delta = solve(&ata, &atb, unknowns).ok_or_else(|| {
            ChangeError::Degenerate(
                "the stable surface does not constrain every degree of freedom (planar or too few \
                 distinct normals)"
                    .into(),
            )
        })?;
        let (omega, dt, ds) = current.update(&delta, unknowns);
        pairs_used = pairs.len();
        rms = frame.rms(&current, &pairs);
        if !(current.rotation.iter().all(|v| v.is_finite())
            && current.translation.iter().all(|v| v.is_finite())
            && current.scale.is_finite()
            && current.scale > 0.0)
        {
            return Err(ChangeError::Degenerate(
                "ICP diverged (non-finite transform)".into(),
            ));
        }
        if omega.norm() < options.tolerance_rotation
            && dt.norm() < options.tolerance_translation
            && ds.abs() < options.tolerance_rotation
        {
            converged = true;
            break;
        }
    }
    let Transform {
        rotation,
        translation,
        scale,
    } = current;
    // Back to the clouds' frame: y + c = s R (x − c) + t + c.
    let world_translation = translation + centre - scale * (rotation * centre);
    let angle = rotation_angle(&rotation).to_degrees();
    Ok(IcpResult {
        rotation: [0, 1, 2].map(|r| [0, 1, 2].map(|c| rotation[(r, c)])),
        translation: [
            world_translation.x,
            world_translation.y,
            world_translation.z,
        ],
        scale,
        rotation_deg: angle,
        iterations,
        converged,
        pairs: pairs_used,
        rms,
    })
}

/// Checks the options and the clouds' sizes and finiteness; returns the number of unknowns of
/// the model (6 rigid, 7 with scale).
fn check_input(
    source: &[[f64; 3]],
    target: &[[f64; 3]],
    options: &IcpOptions,
) -> Result<usize, ChangeError> {
    positive("max_distance", options.max_distance)?;
    if !(options.overlap > 0.0 && options.overlap <= 1.0) {
        return Err(ChangeError::InvalidParameter {
            name: "overlap",
            reason: format!(
                "{} given; a fraction in (0, 1] was expected",
                options.overlap
            ),
        });
    }
    if options.normal_neighbours < 3 {
        return Err(ChangeError::InvalidParameter {
            name: "normal_neighbours",
            reason: format!(
                "{} given; at least 3 were expected",
                options.normal_neighbours
            ),
        });
    }
    let unknowns = match options.model {
        IcpModel::Rigid => 6,
        IcpModel::Similarity => 7,
    };
    if source.len() < 3 * unknowns || target.len() < options.normal_neighbours {
        return Err(ChangeError::NotEnoughData(format!(
            "{} source and {} target points; ICP needs at least {} and {}",
            source.len(),
            target.len(),
            3 * unknowns,
            options.normal_neighbours
        )));
    }
    if let Some(i) = source.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(ChangeError::InvalidInput(format!(
            "source point {i} has a non-finite coordinate"
        )));
    }
    Ok(unknowns)
}

/// The target's normals: PCA of each point's `neighbours` nearest points (`None` where no plane
/// fits), oriented up.
fn target_normals(
    target: &[[f64; 3]],
    index: &PointIndex,
    neighbours: usize,
) -> Vec<Option<Vector3<f64>>> {
    let up = Vector3::z();
    target
        .par_iter()
        .map_init(
            || (Vec::new(), Vec::new()),
            |(indices, positions), p| {
                index.nearest_k(p, neighbours, indices);
                positions.clear();
                positions.extend(indices.iter().map(|&i| target[i as usize]));
                fit_plane(positions, p, &up).map(|f| f.normal)
            },
        )
        .collect()
}

/// The transform `y = s R x + t` in coordinates centred on the target's centroid.
struct Transform {
    rotation: Matrix3<f64>,
    translation: Vector3<f64>,
    scale: f64,
}

impl Transform {
    /// Composes the linearised update `delta` (small rotation, translation, then scale when there
    /// are 7 unknowns) onto the transform; returns the update's rotation vector, translation and
    /// relative scale change.
    fn update(
        &mut self,
        delta: &SVector<f64, 7>,
        unknowns: usize,
    ) -> (Vector3<f64>, Vector3<f64>, f64) {
        let omega = Vector3::new(delta[0], delta[1], delta[2]);
        let dt = Vector3::new(delta[3], delta[4], delta[5]);
        let ds = if unknowns == 7 { delta[6] } else { 0.0 };
        let dr = Rotation3::new(omega).into_inner();
        self.rotation = dr * self.rotation;
        self.translation = (1.0 + ds) * (dr * self.translation) + dt;
        self.scale *= 1.0 + ds;
        (omega, dt, ds)
    }
}

/// What every ICP iteration reads: the target, its index and normals, and the source centred on
/// the target's centroid `centre`.
struct IcpFrame<'a> {
    target: &'a [[f64; 3]],
    index: &'a PointIndex<'a>,
    normals: Vec<Option<Vector3<f64>>>,
    centre: Vector3<f64>,
    source_c: Vec<Vector3<f64>>,
}

impl IcpFrame<'_> {
    /// Target point `j` in centred coordinates.
    fn centred(&self, j: u32) -> Vector3<f64> {
        Vector3::from(self.target[j as usize]) - self.centre
    }

    /// Fills `pairs` with (squared distance, source, target) of every transformed source point's
    /// nearest target point within `max_d2` that has a normal, trimmed to the `overlap` fraction
    /// of smallest distances; an error when fewer than three per unknown remain.
    fn trimmed_pairs(
        &self,
        t: &Transform,
        max_d2: f64,
        options: &IcpOptions,
        unknowns: usize,
        pairs: &mut Vec<(f64, usize, u32)>,
    ) -> Result<(), ChangeError> {
        let (rotation, translation, scale, centre) =
            (t.rotation, t.translation, t.scale, self.centre);
        pairs.clear();
        pairs.par_extend(self.source_c.par_iter().enumerate().filter_map(|(i, x)| {
            let y = scale * (rotation * x) + translation + centre;
            let (j, d2) = self.index.nearest(&[y.x, y.y, y.z]);
            (d2 <= max_d2 && self.normals[j as usize].is_some()).then_some((d2, i, j))
        }));
        let keep = ((pairs.len() as f64) * options.overlap).ceil() as usize;
        if keep < 3 * unknowns {
            return Err(ChangeError::NotEnoughData(format!(
                "only {} point pairs within {} m; increase max_distance or check the initial alignment",
                pairs.len(),
                options.max_distance
            )));
        }
        if keep < pairs.len() {
            pairs.select_nth_unstable_by(keep, |a, b| a.0.total_cmp(&b.0));
            pairs.truncate(keep);
        }
        Ok(())
    }

    /// Normal equations `AᵀA`, `Aᵀb` of the linearised point-to-plane distances of the pairs
    /// (rotation, translation, scale), `b` the negated distances.
    fn normal_equations(
        &self,
        t: &Transform,
        pairs: &[(f64, usize, u32)],
    ) -> (SMatrix<f64, 7, 7>, SVector<f64, 7>) {
        let mut ata = SMatrix::<f64, 7, 7>::zeros();
        let mut atb = SVector::<f64, 7>::zeros();
        for &(_, i, j) in pairs {
            let y = t.scale * (t.rotation * self.source_c[i]) + t.translation;
            let q = self.centred(j);
            let n = self.normals[j as usize].unwrap_or_else(Vector3::z);
            let c = y.cross(&n);
            let row =
                SVector::<f64, 7>::from_column_slice(&[c.x, c.y, c.z, n.x, n.y, n.z, n.dot(&y)]);
            let r = n.dot(&(y - q));
            ata += row * row.transpose();
            atb -= row * r;
        }
        (ata, atb)
    }

    /// RMS point-to-plane distance of the pairs under the transform.
    fn rms(&self, t: &Transform, pairs: &[(f64, usize, u32)]) -> f64 {
        let sum_sq: f64 = pairs
            .iter()
            .map(|&(_, i, j)| {
                let y = t.scale * (t.rotation * self.source_c[i]) + t.translation;
                let n = self.normals[j as usize].unwrap_or_else(Vector3::z);
                n.dot(&(y - self.centred(j))).powi(2)
            })
            .sum();
        (sum_sq / pairs.len() as f64).sqrt()
    }
}

/// Solves the first `n` unknowns of the normal equations (Cholesky), `None` when singular.
fn solve(ata: &SMatrix<f64, 7, 7>, atb: &SVector<f64, 7>, n: usize) -> Option<SVector<f64, 7>> {
    let a = ata.view((0, 0), (n, n)).into_owned();
    let b = atb.rows(0, n).into_owned();
    let scale = a.diagonal().max();
    if !(scale > 0.0) {
        return None;
    }
    // Reject near-singular systems: smallest eigenvalue relative to the largest.
    let eig = nalgebra::SymmetricEigen::try_new(a.clone(), 1e-15, 1000)?;
    if !(eig.eigenvalues.min() > 1e-12 * eig.eigenvalues.max()) {
        return None;
    }
    let x = a.cholesky()?.solve(&b);
    let mut out = SVector::<f64, 7>::zeros();
    out.rows_mut(0, n).copy_from(&x);
    Some(out)
}

/// Angle of a rotation matrix, stable near zero (atan2 of sin and cos rather than acos of the
/// trace, which returns NaN when rounding pushes the trace past 3).
pub fn rotation_angle(r: &Matrix3<f64>) -> f64 {
    let sin = 0.5
        * Vector3::new(
            r[(2, 1)] - r[(1, 2)],
            r[(0, 2)] - r[(2, 0)],
            r[(1, 0)] - r[(0, 1)],
        )
        .norm();
    let cos = 0.5 * (r.trace() - 1.0);
    sin.atan2(cos)
}
