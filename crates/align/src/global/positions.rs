//! From averaged rotations to camera centres in the priors' frame. The rotations' arbitrary frame
//! is turned onto the priors' by the baselines: each pair's direction of translation, rotated
//! into the world by the averaged rotations, against the direction between the two images' GNSS
//! positions (a robust Kabsch fit). The centres are then the least-squares compromise between
//! the pairs' directions and the priors, with one unknown offset per flight (a receiver's bias
//! is common to a flight, so the directions across epochs, not the priors, decide where each
//! flight sits against the others).

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

use super::rotations::{OUTLIER_ANGLE, residual_angle};
use super::solve::{BlockOperator, conjugate_gradients};
use super::two_view::TwoView;
use crate::adjust::{CentrePrior, OffsetPrior};

/// Scale of the Geman–McClure weights on direction residuals, radians (5°).
const ROBUST_SCALE: f64 = 5.0 * std::f64::consts::PI / 180.0;
/// Standard deviation of a pair's direction of translation, radians (0.1°): a nominal value
/// that weighs the directions against the priors (a pair with hundreds of inliers gives its
/// direction to better than that, a consumer receiver's centres within a flight scatter by
/// decimetres over baselines of tens of metres); the robust weights do the rest.
const DIRECTION_SIGMA: f64 = 0.1 * std::f64::consts::PI / 180.0;
/// Fewest pairs with a direction and two priors of one flight that the frame needs.
pub(crate) const MIN_FRAME_PAIRS: usize = 6;
/// Smallest ratio of the second to the first singular value of the directions' cross-covariance:
/// below, the directions are (nearly) parallel, as along one strip, and the roll about them is
/// not determined.
const MIN_DIRECTION_SPREAD: f64 = 0.05;
/// Reweighting rounds of the frame and of the centres.
const ROUNDS: usize = 8;

/// Per image: its centre prior (the first given).
fn priors_by_image(images: usize, priors: &[CentrePrior]) -> Vec<Option<&CentrePrior>> {
    let mut by_image = vec![None; images];
    for prior in priors {
        if prior.image < images && by_image[prior.image].is_none() {
            by_image[prior.image] = Some(prior);
        }
    }
    by_image
}

/// A pair's baseline direction in the rotations' frame: `c_b − c_a ∝ −R_bᵀ t_ab`.
fn direction(view: &TwoView, rb: &UnitQuaternion<f64>) -> Option<Vector3<f64>> {
    view.translation.map(|t| -(rb.inverse() * t))
}

/// Views consistent with the averaged rotations and with a direction: (view, direction in the
/// rotations' frame).
pub(crate) fn directed_views<'v>(
    views: &'v [TwoView],
    rotations: &[Option<UnitQuaternion<f64>>],
) -> Vec<(&'v TwoView, Vector3<f64>)> {
    views
        .iter()
        .filter_map(|v| {
            let (ra, rb) = (rotations[v.a]?, rotations[v.b]?);
            if residual_angle(v, &ra, &rb) > OUTLIER_ANGLE {
                return None;
            }
            direction(v, &rb).map(|d| (v, d))
        })
        .collect()
}

/// The rotation that takes the rotations' frame to the priors': the robust Kabsch fit of the
/// pairs' directions onto the directions between their images' priors, over pairs whose two
/// priors belong to one flight (a bias common to both cancels). `None` with fewer than
/// [`MIN_FRAME_PAIRS`] such pairs, or when their directions are all nearly parallel (one strip:
/// the roll about it is free).
pub(crate) fn frame_rotation(
    directed: &[(&TwoView, Vector3<f64>)],
    priors: &[CentrePrior],
    images: usize,
) -> Option<UnitQuaternion<f64>> {
    let by_image = priors_by_image(images, priors);
    let pairs: Vec<(Vector3<f64>, Vector3<f64>, f64)> = directed
        .iter()
        .filter_map(|(v, d)| {
            let (pa, pb) = (by_image[v.a]?, by_image[v.b]?);
            if pa.offset != pb.offset {
                return None;
            }
            let baseline = pb.position - pa.position;
            let length = baseline.norm();
            (length > 0.0).then(|| (*d, baseline / length, length * length))
        })
        .collect();
    if pairs.len() < MIN_FRAME_PAIRS {
        return None;
    }
    let mut weights: Vec<f64> = pairs.iter().map(|p| p.2).collect();
    let mut q = Matrix3::identity();
    for _ in 0..ROUNDS {
        let mut m = Matrix3::zeros();
        for ((d, u, _), w) in pairs.iter().zip(&weights) {
            m += *w * u * d.transpose();
        }
        let svd = m.svd(true, true);
        let mut singular: Vec<f64> = svd.singular_values.iter().copied().collect();
        singular.sort_by(|a, b| b.total_cmp(a));
        if !(singular[1] > MIN_DIRECTION_SPREAD * singular[0]) {
            return None;
        }
        let (u, v_t) = (svd.u?, svd.v_t?);
        let mut s = Matrix3::identity();
        s[(2, 2)] = (u * v_t).determinant().signum();
        q = u * s * v_t;
        for ((d, u, length2), w) in pairs.iter().zip(weights.iter_mut()) {
            let angle = (q * d).angle(u);
            let s2 = ROBUST_SCALE * ROBUST_SCALE;
            *w = length2 * (s2 / (s2 + angle * angle)).powi(2);
        }
    }
    let rotation = nalgebra::Rotation3::from_matrix_unchecked(q);
    Some(UnitQuaternion::from_rotation_matrix(&rotation))
}

/// What [`solve_centres`] places.
pub(crate) struct Placed {
    /// Per image: its centre, for the images with a prior.
    pub centres: Vec<Option<Vector3<f64>>>,
    /// Per flight: its GNSS offset (measured minus true centre).
    pub offsets: Vec<Vector3<f64>>,
}

/// One prior in the centres' normal equations.
struct PriorTerm {
    node: usize,
    flight: Option<usize>,
    weight: Matrix3<f64>,
    measured: Vector3<f64>,
}

/// The centres (priors' frame) of the images with a prior (only those with a rotation have
/// directed pairs), and each flight's offset, from the directed pairs (already in the priors' frame) and the priors. `None` when
/// the system cannot be solved (no prior among the images).
pub(crate) fn solve_centres(
    images: usize,
    directed: &[(&TwoView, Vector3<f64>)],
    priors: &[CentrePrior],
    offsets: &[OffsetPrior],
) -> Option<Placed> {
    let by_image = priors_by_image(images, priors);
    let mut index = vec![usize::MAX; images];
    let nodes: Vec<usize> = (0..images).filter(|&i| by_image[i].is_some()).collect();
    if nodes.is_empty() {
        return None;
    }
    for (k, &i) in nodes.iter().enumerate() {
        index[i] = k;
    }
    let flights = offsets.len();
    let usable: Vec<(usize, usize, Vector3<f64>, f64)> = directed
        .iter()
        .filter(|(v, _)| index[v.a] != usize::MAX && index[v.b] != usize::MAX)
        .filter_map(|(v, d)| {
            let (pa, pb) = (by_image[v.a]?, by_image[v.b]?);
            let length = (pb.position - pa.position).norm().max(1e-3);
            Some((index[v.a], index[v.b], d.normalize(), length))
        })
        .collect();
    let mut system = PositionSystem {
        nodes: nodes.len(),
        edges: Vec::with_capacity(usable.len()),
        priors: nodes
            .iter()
            .enumerate()
            .filter_map(|(k, &i)| {
                let p = by_image[i]?;
                let w = weight(p.sigma_xy, p.sigma_z);
                Some(PriorTerm {
                    node: k,
                    flight: p.offset.filter(|&f| f < flights),
                    weight: w,
                    measured: p.position,
                })
            })
            .collect(),
        offset_weights: offsets
            .iter()
            .map(|o| weight(o.sigma_xy, o.sigma_z))
            .collect(),
    };
    let mut robust = vec![1.0; usable.len()];
    let mut solution = Vec::new();
    for _ in 0..ROUNDS {
        system.edges.clear();
        for ((i, j, u, length), r) in usable.iter().zip(&robust) {
            let projector = Matrix3::identity() - u * u.transpose();
            let w = r / (DIRECTION_SIGMA * length).powi(2);
            system.edges.push((*i, *j, projector * w));
        }
        let rhs = system.right_hand_side();
        let (x, _) = conjugate_gradients(&system, &rhs, 20 * rhs.len() + 100)?;
        for ((i, j, u, _), r) in usable.iter().zip(robust.iter_mut()) {
            let baseline = x[*j] - x[*i];
            let angle = if baseline.norm() > 0.0 {
                baseline.angle(u)
            } else {
                0.0
            };
            let s2 = ROBUST_SCALE * ROBUST_SCALE;
            *r = (s2 / (s2 + angle * angle)).powi(2);
        }
        solution = x;
    }
    let mut centres = vec![None; images];
    for (k, &i) in nodes.iter().enumerate() {
        centres[i] = Some(solution[k]);
    }
    Some(Placed {
        centres,
        offsets: solution[nodes.len()..].to_vec(),
    })
}

/// The inverse variances (east, north, up) of σ horizontal and vertical.
fn weight(sigma_xy: f64, sigma_z: f64) -> Matrix3<f64> {
    Matrix3::from_diagonal(&Vector3::new(
        sigma_xy.powi(-2),
        sigma_xy.powi(-2),
        sigma_z.powi(-2),
    ))
}

/// The normal equations of the centres: unknowns are the nodes' centres, then the flights'
/// offsets. Direction residual `P_u (c_j − c_i)`, prior residual `c_k + o_f − g_k`, offset
/// residual `o_f`.
struct PositionSystem {
    nodes: usize,
    /// (i, j, w P_u).
    edges: Vec<(usize, usize, Matrix3<f64>)>,
    priors: Vec<PriorTerm>,
    offset_weights: Vec<Matrix3<f64>>,
}

impl PositionSystem {
    fn right_hand_side(&self) -> Vec<Vector3<f64>> {
        let mut b = vec![Vector3::zeros(); self.len()];
        for p in &self.priors {
            let wg = p.weight * p.measured;
            b[p.node] += wg;
            if let Some(f) = p.flight {
                b[self.nodes + f] += wg;
            }
        }
        b
    }
}

impl BlockOperator for PositionSystem {
    fn len(&self) -> usize {
        self.nodes + self.offset_weights.len()
    }
    fn apply(&self, x: &[Vector3<f64>], y: &mut [Vector3<f64>]) {
        y.fill(Vector3::zeros());
        for (i, j, m) in &self.edges {
            let d = m * (x[*j] - x[*i]);
            y[*j] += d;
            y[*i] -= d;
        }
        for p in &self.priors {
            let r = match p.flight {
                Some(f) => x[p.node] + x[self.nodes + f],
                None => x[p.node],
            };
            let wr = p.weight * r;
            y[p.node] += wr;
            if let Some(f) = p.flight {
                y[self.nodes + f] += wr;
            }
        }
        for (f, w) in self.offset_weights.iter().enumerate() {
            y[self.nodes + f] += w * x[self.nodes + f];
        }
    }
    fn diagonal(&self) -> Vec<Matrix3<f64>> {
        let mut blocks = vec![Matrix3::zeros(); self.len()];
        for (i, j, m) in &self.edges {
            blocks[*i] += m;
            blocks[*j] += m;
        }
        for p in &self.priors {
            blocks[p.node] += p.weight;
            if let Some(f) = p.flight {
                blocks[self.nodes + f] += p.weight;
            }
        }
        for (f, w) in self.offset_weights.iter().enumerate() {
            blocks[self.nodes + f] += w;
        }
        blocks
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use timesift_core::{Pose, SeededRng};

    fn prior(image: usize, position: Vector3<f64>, offset: Option<usize>) -> CentrePrior {
        CentrePrior {
            image,
            position,
            sigma_xy: 0.5,
            sigma_z: 0.8,
            offset,
        }
    }

    /// Two flights of `n` cameras each over one area, every pair within 25 m connected.
    fn two_flights(rng: &mut SeededRng, n: usize) -> (Vec<Vector3<f64>>, Vec<(usize, usize)>) {
        let centres: Vec<Vector3<f64>> = (0..2 * n)
            .map(|_| {
                Vector3::new(
                    rng.uniform_range(0.0, 60.0),
                    rng.uniform_range(0.0, 40.0),
                    rng.uniform_range(95.0, 105.0),
                )
            })
            .collect();
        let mut pairs = Vec::new();
        for a in 0..centres.len() {
            for b in a + 1..centres.len() {
                if (centres[a] - centres[b]).norm() < 25.0 {
                    pairs.push((a, b));
                }
            }
        }
        (centres, pairs)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(16))]
        /// Cameras with random attitudes, their pairs' relative poses taken from the true poses
        /// (x_b = R_ab x_a + t), their rotations given in a frame turned by a random rotation,
        /// and exact priors, the second flight's biased by an offset: the frame's rotation,
        /// every centre and the offset are recovered exactly.
        #[test]
        fn exact_directions_and_priors_give_the_frame_the_centres_and_the_offset(seed in 0u64..500) {
            let mut rng = SeededRng::new(seed);
            let (centres, pairs) = two_flights(&mut rng, 15);
            let mut turn = || UnitQuaternion::from_scaled_axis(Vector3::new(
                rng.normal(), rng.normal(), rng.normal(),
            ));
            let frame = turn();
            let poses: Vec<Pose> = centres
                .iter()
                .map(|c| Pose::from_rotation_and_center(turn(), c))
                .collect();
            let bias = Vector3::new(2.0, -3.0, 1.5);
            let views: Vec<TwoView> = pairs
                .iter()
                .map(|&(a, b)| {
                    let relative = poses[b] * poses[a].inverse();
                    TwoView {
                        a,
                        b,
                        rotation: relative.rotation,
                        translation: Some(relative.translation.normalize()),
                        inliers: 100,
                    }
                })
                .collect();
            // Cam from averaging frame = cam from priors' frame ∘ priors' from averaging frame.
            let rotations: Vec<_> = poses.iter().map(|p| Some(p.rotation * frame)).collect();
            let priors: Vec<CentrePrior> = centres
                .iter()
                .enumerate()
                .map(|(i, c)| {
                    let flight = usize::from(i >= 15);
                    let offset = (flight == 1).then_some(0);
                    prior(i, c + if flight == 1 { bias } else { Vector3::zeros() }, offset)
                })
                .collect();
            // A loose zero-mean prior on the offset, so that the exact answer is the optimum.
            let offsets = [OffsetPrior { name: "second".into(), sigma_xy: 1e4, sigma_z: 1e4 }];
            let directed = directed_views(&views, &rotations);
            prop_assert_eq!(directed.len(), views.len());
            let q = frame_rotation(&directed, &priors, centres.len()).unwrap();
            prop_assert!((q.inverse() * frame).angle() < 1e-9);
            let directed: Vec<_> = directed.into_iter().map(|(v, d)| (v, q * d)).collect();
            let placed = solve_centres(centres.len(), &directed, &priors, &offsets).unwrap();
            for (g, c) in placed.centres.iter().zip(&centres) {
                prop_assert!((g.unwrap() - c).norm() < 1e-6, "{:?} {:?}", g, c);
            }
            prop_assert!((placed.offsets[0] - bias).norm() < 1e-6);
        }
    }

    /// Pairs along one strip only (every direction parallel): the roll about the strip is not
    /// determined, and no frame is returned.
    #[test]
    fn one_strip_does_not_determine_the_frame() {
        let views: Vec<TwoView> = (0..9)
            .map(|k| TwoView {
                a: k,
                b: k + 1,
                rotation: UnitQuaternion::identity(),
                translation: Some(-Vector3::x()),
                inliers: 100,
            })
            .collect();
        let rotations = vec![Some(UnitQuaternion::identity()); 10];
        let directed = directed_views(&views, &rotations);
        let priors: Vec<CentrePrior> = (0..10)
            .map(|k| prior(k, Vector3::new(10.0 * k as f64, 0.0, 100.0), None))
            .collect();
        assert_eq!(directed.len(), 9);
        assert!(frame_rotation(&directed, &priors, 10).is_none());
    }

    /// Without pairs that have two priors of one flight the frame is not determined.
    #[test]
    fn the_frame_needs_pairs_within_a_flight() {
        let view = TwoView {
            a: 0,
            b: 1,
            rotation: UnitQuaternion::identity(),
            translation: Some(Vector3::x()),
            inliers: 100,
        };
        let views = vec![view; 10];
        let rotations = vec![Some(UnitQuaternion::identity()); 2];
        let directed = directed_views(&views, &rotations);
        let priors = [
            prior(0, Vector3::zeros(), Some(0)),
            prior(1, Vector3::x(), Some(1)),
        ];
        assert!(frame_rotation(&directed, &priors, 2).is_none());
    }
}
