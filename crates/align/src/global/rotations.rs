//! Rotation averaging: every image's rotation from the relative rotations of the pairs, in one
//! arbitrary frame. A maximum spanning tree over the inlier counts gives the start; iteratively
//! reweighted least squares on the Lie algebra (Chatterjee & Govindu 2013; the Geman–McClure
//! weights GLOMAP uses) refines it, so that a wrong relative rotation, which a tree would pass
//! on to every image beyond it, weighs next to nothing once the others disagree with it.

use std::collections::VecDeque;

use nalgebra::{UnitQuaternion, Vector3};

use super::solve::{Laplacian, conjugate_gradients};
use super::two_view::TwoView;

/// Scale of the Geman–McClure weights, radians (5°).
const ROBUST_SCALE: f64 = 5.0 * std::f64::consts::PI / 180.0;
/// An edge whose residual after averaging exceeds this is an outlier, radians (10°).
pub(crate) const OUTLIER_ANGLE: f64 = 10.0 * std::f64::consts::PI / 180.0;
/// Reweighting rounds at most.
const MAX_ROUNDS: usize = 100;
/// The rounds stop when no rotation moved by more than this, radians.
const CONVERGED: f64 = 1e-9;

/// The residual rotation angle of `view` under absolute rotations `ri`, `rj` (cam from world):
/// the angle of `R_ab⁻¹ R_b R_aᵀ`, radians.
pub(crate) fn residual_angle(
    view: &TwoView,
    ra: &UnitQuaternion<f64>,
    rb: &UnitQuaternion<f64>,
) -> f64 {
    (view.rotation.inverse() * rb * ra.inverse()).angle()
}

/// Per image: its rotation (cam from world) in one arbitrary frame, for the images of the
/// largest connected component of `views`; `None` elsewhere.
pub(crate) fn average_rotations(
    images: usize,
    views: &[TwoView],
) -> Vec<Option<UnitQuaternion<f64>>> {
    let mut rotations = spanning_tree(images, views);
    // Nodes of the component, renumbered for the solver.
    let mut index = vec![usize::MAX; images];
    let nodes: Vec<usize> = (0..images).filter(|&i| rotations[i].is_some()).collect();
    for (k, &i) in nodes.iter().enumerate() {
        index[i] = k;
    }
    let inside: Vec<&TwoView> = views
        .iter()
        .filter(|v| index[v.a] != usize::MAX && index[v.b] != usize::MAX)
        .collect();
    if nodes.len() < 2 {
        return rotations;
    }
    let mut edges: Vec<(usize, usize, f64)> = Vec::with_capacity(inside.len());
    let mut rhs = vec![Vector3::zeros(); nodes.len()];
    for _ in 0..MAX_ROUNDS {
        edges.clear();
        rhs.fill(Vector3::zeros());
        for view in &inside {
            let (Some(ra), Some(rb)) = (rotations[view.a], rotations[view.b]) else {
                continue;
            };
            // E = R_ab⁻¹ R_b R_aᵀ; with R ← R exp(w) (w in the world frame),
            // log E + R_a (w_b − w_a) ≈ 0, so w_b − w_a = −R_aᵀ log E.
            let error = view.rotation.inverse() * rb * ra.inverse();
            let target = -(ra.inverse() * error.scaled_axis());
            let r2 = error.angle().powi(2);
            let s2 = ROBUST_SCALE * ROBUST_SCALE;
            let weight = (s2 / (s2 + r2)).powi(2);
            let (i, j) = (index[view.a], index[view.b]);
            edges.push((i, j, weight));
            // Normal equations of w_j − w_i = target with weight: row i gets −w·target, j +.
            rhs[i] -= weight * target;
            rhs[j] += weight * target;
        }
        let mean_weight = edges.iter().map(|e| e.2).sum::<f64>() / edges.len().max(1) as f64;
        let laplacian = Laplacian::new(nodes.len(), &edges, (0, mean_weight));
        let Some((update, _)) = conjugate_gradients(&laplacian, &rhs, 10 * nodes.len() + 200)
        else {
            tracing::warn!("rotation averaging: the linear system did not converge; stopping");
            break;
        };
        let mut largest: f64 = 0.0;
        for (k, &i) in nodes.iter().enumerate() {
            let w = update[k];
            largest = largest.max(w.norm());
            if let Some(r) = &mut rotations[i] {
                *r *= UnitQuaternion::from_scaled_axis(w);
            }
        }
        if largest < CONVERGED {
            break;
        }
    }
    rotations
}

/// The rotations a maximum spanning tree over the inlier counts propagates from the best
/// connected image of the largest component (Kruskal, then breadth first).
fn spanning_tree(images: usize, views: &[TwoView]) -> Vec<Option<UnitQuaternion<f64>>> {
    let mut order: Vec<usize> = (0..views.len()).collect();
    order.sort_by(|&x, &y| {
        views[y]
            .inliers
            .cmp(&views[x].inliers)
            .then((views[x].a, views[x].b).cmp(&(views[y].a, views[y].b)))
    });
    let mut parent: Vec<usize> = (0..images).collect();
    fn find(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let mut tree: Vec<Vec<(usize, usize)>> = vec![Vec::new(); images];
    for &e in &order {
        let (a, b) = (views[e].a, views[e].b);
        let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
        if ra != rb {
            parent[ra] = rb;
            tree[a].push((b, e));
            tree[b].push((a, e));
        }
    }
    let mut size = vec![0usize; images];
    for i in 0..images {
        let root = find(&mut parent, i);
        size[root] += 1;
    }
    let mut rotations = vec![None; images];
    let Some(root) = (0..images)
        .filter(|&i| !tree[i].is_empty())
        .max_by_key(|&i| {
            (
                size[find(&mut parent, i)],
                tree[i].len(),
                std::cmp::Reverse(i),
            )
        })
    else {
        return rotations;
    };
    rotations[root] = Some(UnitQuaternion::identity());
    let mut queue = VecDeque::from([root]);
    while let Some(i) = queue.pop_front() {
        let Some(ri) = rotations[i] else { continue };
        for &(j, e) in &tree[i] {
            if rotations[j].is_some() {
                continue;
            }
            let view = &views[e];
            // R_b = R_ab R_a.
            rotations[j] = Some(if view.a == i {
                view.rotation * ri
            } else {
                view.rotation.inverse() * ri
            });
            queue.push_back(j);
        }
    }
    rotations
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use timesift_core::SeededRng;

    fn random_rotation(rng: &mut SeededRng, scale: f64) -> UnitQuaternion<f64> {
        UnitQuaternion::from_scaled_axis(Vector3::new(
            rng.normal() * scale,
            rng.normal() * scale,
            rng.normal() * scale,
        ))
    }

    /// The relative rotations of random absolute ones over a random connected graph (a chain
    /// plus chords), each perturbed by `noise` radians, a share of them replaced by random ones.
    fn views(
        truth: &[UnitQuaternion<f64>],
        chords: usize,
        noise: f64,
        wrong: usize,
        rng: &mut SeededRng,
    ) -> Vec<TwoView> {
        let n = truth.len();
        let mut pairs: Vec<(usize, usize)> = (1..n).map(|k| (k - 1, k)).collect();
        for _ in 0..chords {
            let a = rng.uniform_range(0.0, n as f64) as usize % n;
            let b = rng.uniform_range(0.0, n as f64) as usize % n;
            if a < b {
                pairs.push((a, b));
            }
        }
        pairs
            .into_iter()
            .enumerate()
            .map(|(k, (a, b))| {
                let mut rotation = random_rotation(rng, noise) * truth[b] * truth[a].inverse();
                // The chain keeps its true edges so the graph stays connected by good ones; a
                // wrong model explains fewer matches than a right one.
                let mut inliers = 100 + k % 7;
                if k >= n - 1 && k < n - 1 + wrong {
                    // Wrong by 20° to 170° about a random axis: clearly a wrong model, not noise.
                    let axis = Vector3::new(rng.normal(), rng.normal(), rng.normal()).normalize();
                    let angle = rng.uniform_range(20f64.to_radians(), 170f64.to_radians());
                    rotation = UnitQuaternion::from_scaled_axis(axis * angle) * rotation;
                    inliers = 40;
                }
                TwoView {
                    a,
                    b,
                    rotation,
                    translation: None,
                    inliers,
                }
            })
            .collect()
    }

    /// The largest angle between `got` and `truth` after one global rotation between them (the
    /// frame is arbitrary): the mean of the images' own (sign-aligned quaternions, normalised).
    fn max_error(got: &[Option<UnitQuaternion<f64>>], truth: &[UnitQuaternion<f64>]) -> f64 {
        let first = got[0].unwrap().inverse() * truth[0];
        let mut sum = nalgebra::Vector4::zeros();
        for (g, t) in got.iter().zip(truth) {
            let q = (g.unwrap().inverse() * t).into_inner().coords;
            sum += if q.dot(&first.into_inner().coords) < 0.0 {
                -q
            } else {
                q
            };
        }
        let align = UnitQuaternion::from_quaternion(nalgebra::Quaternion::from(sum));
        got.iter()
            .zip(truth)
            .map(|(g, t)| (g.unwrap() * align * t.inverse()).angle())
            .fold(0.0, f64::max)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        /// Exact relative rotations give the absolute ones exactly (up to the frame).
        #[test]
        fn exact_relative_rotations_are_recovered_exactly(seed in 0u64..1000, n in 3usize..40) {
            let mut rng = SeededRng::new(seed);
            let truth: Vec<_> = (0..n).map(|_| random_rotation(&mut rng, 1.0)).collect();
            let views = views(&truth, 3 * n, 0.0, 0, &mut rng);
            let got = average_rotations(n, &views);
            prop_assert!(max_error(&got, &truth) < 1e-9);
        }

        /// With 0.5° of noise on every edge and n/2 of the chords wrong (by 20°–170° about a
        /// random axis), every rotation is within 1° of the truth: along the
        /// chain of 10–40 true edges alone the noise would add up to degrees, so the chords,
        /// and the weights that leave the wrong ones out, are what gets them there.
        #[test]
        fn noisy_rotations_with_outliers_are_within_a_degree(seed in 0u64..1000, n in 10usize..40) {
            let mut rng = SeededRng::new(seed);
            let truth: Vec<_> = (0..n).map(|_| random_rotation(&mut rng, 1.0)).collect();
            let noise = 0.5f64.to_radians() / 3f64.sqrt();
            // Some 15 pairs per image, as a drone block has (a chain and its chords).
            let views = views(&truth, 15 * n, noise, n / 2, &mut rng);
            let got = average_rotations(n, &views);
            prop_assert!(max_error(&got, &truth) < 1f64.to_radians());
        }
    }

    /// Two components: only the larger is oriented.
    #[test]
    fn only_the_largest_component_is_oriented() {
        let r = UnitQuaternion::identity();
        let view = |a, b| TwoView {
            a,
            b,
            rotation: r,
            translation: None,
            inliers: 50,
        };
        let views = [view(0, 1), view(1, 2), view(3, 4)];
        let got = average_rotations(5, &views);
        assert_eq!(got.iter().filter(|r| r.is_some()).count(), 3);
        assert!(got[3].is_none() && got[4].is_none());
    }
}
