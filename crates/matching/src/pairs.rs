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
                        let d = ((pa[0] - pb[0]).powi(2)
                            + (pa[1] - pb[1]).powi(2)
                            + (pa[2] - pb[2]).powi(2))
                        .sqrt();
                        Some((d, b))
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

/// Pairs for a multi-epoch block: within each epoch by `within`; between epochs, each image with
/// its `across` nearest images of every other epoch (by prior camera centre; every image of the
/// other epoch when priors are missing), so that every epoch is linked to every other.
pub fn epoch_aware(
    epoch_of: &[EpochId],
    positions: &[Option<[f64; 3]>],
    within: PairPolicy,
    across: usize,
) -> Vec<(usize, usize)> {
    let epochs: BTreeSet<EpochId> = epoch_of.iter().copied().collect();
    let members =
        |e: EpochId| -> Vec<usize> { (0..epoch_of.len()).filter(|&i| epoch_of[i] == e).collect() };
    let mut out: BTreeSet<(usize, usize)> = BTreeSet::new();
    for &e in &epochs {
        out.extend(select(&members(e), positions, within));
    }
    for &e in &epochs {
        for &f in epochs.iter().filter(|&&f| f > e) {
            let (a, b) = (members(e), members(f));
            for (from, to) in [(&a, &b), (&b, &a)] {
                for &i in from {
                    let mut candidates: Vec<usize> = to.clone();
                    candidates.push(i);
                    out.extend(
                        select(
                            &candidates,
                            positions,
                            PairPolicy::Spatial {
                                neighbours: across,
                                max_distance: None,
                            },
                        )
                        .into_iter()
                        .filter(|&(x, y)| x == i || y == i),
                    );
                }
            }
        }
    }
    out.into_iter().collect()
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
}
