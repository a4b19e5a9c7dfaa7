//! Which image pairs to match. Images are indices into the project's image list; pairs are
//! `(i, j)` with `i < j`, sorted and without repeats.

use std::collections::BTreeSet;

use timesift_core::EpochId;

/// How pairs are chosen within a set of images.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PairPolicy {
    /// Every pair.
    Exhaustive,
    /// Each image with the next `overlap` images in capture order.
    Sequential {
        /// How many following images each image is paired with.
        overlap: usize,
    },
    /// Each image with its `neighbours` nearest images by prior camera centre, within
    /// `max_distance` (metres) when given. Images without a prior fall back to exhaustive.
    Spatial {
        /// How many nearest images each image is paired with.
        neighbours: usize,
        /// Farthest distance between paired centres, metres.
        max_distance: Option<f64>,
    },
}

/// Pairs among `images` (indices into `positions`) by `policy`.
pub fn select(
    images: &[usize],
    positions: &[Option<[f64; 3]>],
    policy: PairPolicy,
) -> Vec<(usize, usize)> {
    let mut out = BTreeSet::new();
    let mut add = |a: usize, b: usize| {
        if a != b {
            out.insert((a.min(b), a.max(b)));
        }
    };
    match policy {
        PairPolicy::Exhaustive => {
            for (k, &a) in images.iter().enumerate() {
                for &b in &images[k + 1..] {
                    add(a, b);
                }
            }
        }
        PairPolicy::Sequential { overlap } => {
            for (k, &a) in images.iter().enumerate() {
                for &b in images.iter().skip(k + 1).take(overlap) {
                    add(a, b);
                }
            }
        }
        PairPolicy::Spatial {
            neighbours,
            max_distance,
        } => {
            for &a in images {
                let Some(pa) = positions.get(a).copied().flatten() else {
                    for &b in images {
                        add(a, b);
                    }
                    continue;
                };
                let mut near: Vec<(f64, usize)> = images
                    .iter()
                    .filter(|&&b| b != a)
                    .filter_map(|&b| {
                        let pb = positions.get(b).copied().flatten()?;
                        Some((distance(pa, pb), b))
                    })
                    .filter(|(d, _)| max_distance.is_none_or(|m| *d <= m))
                    .collect();
                near.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
                for &(_, b) in near.iter().take(neighbours) {
                    add(a, b);
                }
            }
        }
    }
    out.into_iter().collect()
}

/// Which epochs an epoch is matched with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EpochPartners {
    /// Every other epoch: pairs per image grow with the number of epochs.
    All,
    /// The `neighbours` epochs before and after it (in the order of the ids: time order) and
    /// the `reference` epoch: pairs per image stay bounded however many epochs the archive
    /// holds, and every epoch is still tied to the datum's epoch directly.
    Nearest {
        /// Epochs on each side.
        neighbours: usize,
        /// The epoch every epoch is matched with.
        reference: EpochId,
    },
}

impl EpochPartners {
    /// Whether the epochs of rank `a` and `b` (their positions among the block's epochs, in
    /// order), ids `ea` and `eb`, are matched.
    fn pairs(self, (a, ea): (usize, EpochId), (b, eb): (usize, EpochId)) -> bool {
        match self {
            EpochPartners::All => true,
            EpochPartners::Nearest {
                neighbours,
                reference,
            } => a.abs_diff(b) <= neighbours || ea == reference || eb == reference,
        }
    }
}

/// Pairs for a multi-epoch block: within each epoch by `within`; between each epoch and its
/// `partners`, each image with its `across` nearest images of the other epoch (by prior camera
/// centre; every image of the other epoch when priors are missing).
pub fn epoch_aware(
    epoch_of: &[EpochId],
    positions: &[Option<[f64; 3]>],
    within: PairPolicy,
    across: usize,
    partners: EpochPartners,
) -> Vec<(usize, usize)> {
    let epochs: Vec<EpochId> = epoch_of
        .iter()
        .copied()
        .collect::<BTreeSet<EpochId>>()
        .into_iter()
        .collect();
    let members: Vec<Vec<usize>> = epochs
        .iter()
        .map(|&e| (0..epoch_of.len()).filter(|&i| epoch_of[i] == e).collect())
        .collect();
    let mut out: BTreeSet<(usize, usize)> = BTreeSet::new();
    for m in &members {
        out.extend(select(m, positions, within));
    }
    for (ra, &e) in epochs.iter().enumerate() {
        for (rb, &f) in epochs.iter().enumerate().skip(ra + 1) {
            if !partners.pairs((ra, e), (rb, f)) {
                continue;
            }
            let (a, b) = (&members[ra], &members[rb]);
            for (from, to) in [(a, b), (b, a)] {
                let kth: Vec<Option<(f64, usize)>> = to
                    .iter()
                    .map(|&j| kth_nearest(j, to, positions, across))
                    .collect();
                for &i in from {
                    out.extend(nearest_in(i, to, &kth, positions, across));
                }
            }
        }
    }
    out.into_iter().collect()
}

/// Distance between two prior centres.
fn distance(p: [f64; 3], q: [f64; 3]) -> f64 {
    ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
}

/// The (distance, image) key of the `k`-th nearest image to `j` among `others` (`j` left out),
/// `None` when there are fewer than `k` with a prior or `j` has none.
fn kth_nearest(
    j: usize,
    others: &[usize],
    positions: &[Option<[f64; 3]>],
    k: usize,
) -> Option<(f64, usize)> {
    let pj = positions.get(j).copied().flatten()?;
    let mut keys: Vec<(f64, usize)> = others
        .iter()
        .filter(|&&m| m != j)
        .filter_map(|&m| Some((distance(pj, positions.get(m).copied().flatten()?), m)))
        .collect();
    if k == 0 || keys.len() < k {
        return None;
    }
    keys.select_nth_unstable_by(k - 1, |x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
    Some(keys[k - 1])
}

/// The pairs of image `i` with the images `others` of another epoch: its `k` nearest among
/// them, and each of them that has `i` among its own `k` nearest once `i` joins them (`kth`:
/// their `k`-th nearest key among themselves). An image without a prior is paired with all.
fn nearest_in(
    i: usize,
    others: &[usize],
    kth: &[Option<(f64, usize)>],
    positions: &[Option<[f64; 3]>],
    k: usize,
) -> Vec<(usize, usize)> {
    let pair = |j: usize| (i.min(j), i.max(j));
    let Some(pi) = positions.get(i).copied().flatten() else {
        return others.iter().map(|&j| pair(j)).collect();
    };
    let mut near: Vec<(f64, usize)> = Vec::with_capacity(others.len());
    let mut out = Vec::new();
    for (&j, kth) in others.iter().zip(kth) {
        let Some(pj) = positions.get(j).copied().flatten() else {
            out.push(pair(j));
            continue;
        };
        let key = (distance(pi, pj), i);
        near.push((key.0, j));
        let among_its_nearest = match kth {
            None => true,
            Some(kth) => key.0.total_cmp(&kth.0).then(key.1.cmp(&kth.1)).is_lt(),
        };
        if k > 0 && among_its_nearest {
            out.push(pair(j));
        }
    }
    near.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)));
    out.extend(near.iter().take(k).map(|&(_, j)| pair(j)));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn policies() {
        let images: Vec<usize> = (0..5).collect();
        let none = vec![None; 5];
        assert_eq!(select(&images, &none, PairPolicy::Exhaustive).len(), 10);
        assert_eq!(
            select(&images, &none, PairPolicy::Sequential { overlap: 2 }),
            vec![(0, 1), (0, 2), (1, 2), (1, 3), (2, 3), (2, 4), (3, 4)]
        );
        let line: Vec<Option<[f64; 3]>> =
            (0..5).map(|i| Some([i as f64 * 10.0, 0.0, 0.0])).collect();
        let spatial = select(
            &images,
            &line,
            PairPolicy::Spatial {
                neighbours: 1,
                max_distance: None,
            },
        );
        assert_eq!(spatial, vec![(0, 1), (1, 2), (2, 3), (3, 4)]);
        let radius = select(
            &images,
            &line,
            PairPolicy::Spatial {
                neighbours: 10,
                max_distance: Some(15.0),
            },
        );
        assert_eq!(radius, vec![(0, 1), (1, 2), (2, 3), (3, 4)]);
    }

    #[test]
    fn every_epoch_is_linked_to_every_other() {
        // Three epochs of 4 images flown over the same line.
        let epoch_of: Vec<EpochId> = (0..12).map(|i| EpochId(i / 4)).collect();
        let positions: Vec<Option<[f64; 3]>> = (0..12)
            .map(|i| Some([(i % 4) as f64 * 10.0 + (i / 4) as f64, 0.0, 100.0]))
            .collect();
        let pairs = epoch_aware(
            &epoch_of,
            &positions,
            PairPolicy::Sequential { overlap: 1 },
            1,
            EpochPartners::All,
        );
        for (e, f) in [(0, 1), (0, 2), (1, 2)] {
            assert!(
                pairs
                    .iter()
                    .any(|&(a, b)| epoch_of[a] == EpochId(e) && epoch_of[b] == EpochId(f)),
                "epochs {e} and {f} not linked"
            );
        }
        // Inter-epoch pairs join images over the same spot.
        assert!(pairs.contains(&(0, 4)) && pairs.contains(&(3, 7)));
        assert!(!pairs.contains(&(0, 7)));
    }

    /// The pairs between two epochs as first written: for each image, `select` over the other
    /// epoch plus itself, keeping the pairs that hold it.
    fn across_as_first_written(
        a: &[usize],
        b: &[usize],
        positions: &[Option<[f64; 3]>],
        across: usize,
    ) -> BTreeSet<(usize, usize)> {
        let mut out = BTreeSet::new();
        for (from, to) in [(a, b), (b, a)] {
            for &i in from {
                let mut candidates = to.to_vec();
                candidates.push(i);
                let policy = PairPolicy::Spatial {
                    neighbours: across,
                    max_distance: None,
                };
                out.extend(
                    select(&candidates, positions, policy)
                        .into_iter()
                        .filter(|&(x, y)| x == i || y == i),
                );
            }
        }
        out
    }

    proptest::proptest! {
        /// Every pair of epochs matched: the same pairs as the first (quadratic per image)
        /// formulation, priors missing or not.
        #[test]
        fn all_partners_give_the_pairs_of_the_first_formulation(
            layout in proptest::collection::vec((0u32..3, proptest::option::weighted(0.9, (0.0..50.0f64, 0.0..50.0f64))), 2..40),
            across in 0usize..4,
        ) {
            let epoch_of: Vec<EpochId> = layout.iter().map(|(e, _)| EpochId(*e)).collect();
            let positions: Vec<Option<[f64; 3]>> =
                layout.iter().map(|(_, p)| p.map(|(x, y)| [x, y, 100.0])).collect();
            let within = PairPolicy::Sequential { overlap: 1 };
            let pairs = epoch_aware(&epoch_of, &positions, within, across, EpochPartners::All);
            let mut expected = BTreeSet::new();
            for e in 0..3 {
                let m: Vec<usize> = (0..layout.len()).filter(|&i| epoch_of[i] == EpochId(e)).collect();
                expected.extend(select(&m, &positions, within));
            }
            for e in 0..3 {
                for f in e + 1..3 {
                    let a: Vec<usize> = (0..layout.len()).filter(|&i| epoch_of[i] == EpochId(e)).collect();
                    let b: Vec<usize> = (0..layout.len()).filter(|&i| epoch_of[i] == EpochId(f)).collect();
                    expected.extend(across_as_first_written(&a, &b, &positions, across));
                }
            }
            proptest::prop_assert_eq!(pairs, expected.into_iter().collect::<Vec<_>>());
        }
    }

    #[test]
    fn nearest_partners_bound_the_pairs_per_image_and_tie_every_epoch_to_the_reference() {
        // 16 epochs of the same 5 x 5 grid.
        let (epochs, side) = (16u32, 5usize);
        let mut epoch_of = Vec::new();
        let mut positions = Vec::new();
        for e in 0..epochs {
            for k in 0..side * side {
                epoch_of.push(EpochId(e));
                positions.push(Some([
                    (k % side) as f64 * 10.0,
                    (k / side) as f64 * 10.0,
                    50.0,
                ]));
            }
        }
        let within = PairPolicy::Spatial {
            neighbours: 4,
            max_distance: None,
        };
        let partners = EpochPartners::Nearest {
            neighbours: 2,
            reference: EpochId(0),
        };
        let pairs = epoch_aware(&epoch_of, &positions, within, 3, partners);
        let linked = |e: u32, f: u32| {
            pairs.iter().any(|&(a, b)| {
                (epoch_of[a], epoch_of[b]) == (EpochId(e), EpochId(f))
                    || (epoch_of[a], epoch_of[b]) == (EpochId(f), EpochId(e))
            })
        };
        for e in 1..epochs {
            assert!(linked(0, e), "epoch {e} not tied to the reference");
            assert!(linked(e - 1, e), "epochs {} and {e} not tied", e - 1);
        }
        assert!(!linked(5, 8) && !linked(3, 15));
        // Partners of an epoch: the reference and at most 2 either side; each image meets at
        // most 3 images of each partner in its own list plus those that chose it.
        let all = epoch_aware(&epoch_of, &positions, within, 3, EpochPartners::All);
        let per_image = pairs.len() as f64 / epoch_of.len() as f64;
        let per_image_all = all.len() as f64 / epoch_of.len() as f64;
        assert!(
            per_image < 0.5 * per_image_all,
            "{per_image} vs {per_image_all}"
        );
        let mut degree = vec![0usize; epoch_of.len()];
        for &(a, b) in &pairs {
            degree[a] += 1;
            degree[b] += 1;
        }
        let max_partners = 2 * 2 + 1;
        let bound = 2 * 4 + max_partners * 2 * 3 + 15 * 2 * 3;
        assert!(degree.iter().all(|&d| d <= bound));
    }
}
