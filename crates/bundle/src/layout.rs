//! Where each parameter of a bundle problem sits in the solver: which blocks the Schur
//! complement eliminates and the reduced-side column of every free pose, point, intrinsic and
//! offset. Shared by the solver, its preconditioners and the precision estimates, so that none of
//! them recomputes the numbering.

use crate::problem::BundleProblem;

/// Which parameter blocks the Schur complement eliminates. Each observation touches one pose and
/// one point, so either kind forms a block-diagonal set; eliminating the more numerous kind leaves
/// the smaller reduced system (Ceres picks its elimination groups the same way).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Eliminate {
    /// Points (3 × 3 blocks): the usual choice, many points seen by fewer cameras.
    Points,
    /// Poses (6 × 6 blocks): many cameras, few points (camera tracking); the reduced system holds
    /// the points and the intrinsics.
    Poses,
}

/// Index layout: offsets of reduced-side parameters, indices of eliminated blocks.
pub(crate) struct Layout {
    pub(crate) eliminate: Eliminate,
    /// Reduced-side offset of each free pose (points elimination only).
    pub(crate) pose_offset: Vec<Option<usize>>,
    /// Reduced-side offset of each group's free intrinsics.
    pub(crate) group_offset: Vec<Option<usize>>,
    /// Reduced-side offset of each free prior offset (GNSS bias); always on the reduced side.
    pub(crate) bias_offset: Vec<Option<usize>>,
    pub(crate) group_free: Vec<Vec<usize>>,
    /// Reduced-side offset of each free point (poses elimination only).
    pub(crate) point_offset: Vec<Option<usize>>,
    /// Eliminated block of each free point (points elimination only).
    pub(crate) point_index: Vec<Option<usize>>,
    /// Eliminated block of each free pose (poses elimination only).
    pub(crate) pose_index: Vec<Option<usize>>,
    /// Size of the reduced system.
    pub(crate) num_camera_params: usize,
    /// Number of eliminated blocks.
    pub(crate) num_free_points: usize,
}

fn counter(
    flags: impl Iterator<Item = bool>,
    start: &mut usize,
    step: usize,
) -> Vec<Option<usize>> {
    flags
        .map(|free| {
            free.then(|| {
                *start += step;
                *start - step
            })
        })
        .collect()
}

/// Reduced-side offsets of the groups with free intrinsics, numbered from `start` on.
fn group_offsets(group_free: &[Vec<usize>], start: &mut usize) -> Vec<Option<usize>> {
    group_free
        .iter()
        .map(|f| {
            (!f.is_empty()).then(|| {
                *start += f.len();
                *start - f.len()
            })
        })
        .collect()
}

impl Layout {
    /// The layout that eliminates points (the public parameter order: poses, intrinsics, points).
    pub(crate) fn new(p: &BundleProblem) -> Self {
        Self::with(p, Eliminate::Points)
    }

    pub(crate) fn with(p: &BundleProblem, eliminate: Eliminate) -> Self {
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
        let free_poses = p.images.iter().map(|im| !im.fixed);
        let free_points = p.points.iter().map(|pt| !pt.fixed);
        let mut n = 0;
        let mut m = 0;
        let none_i = vec![None; p.images.len()];
        let (pose_offset, pose_index, point_offset, point_index, group_offset, bias_offset);
        match eliminate {
            Eliminate::Points => {
                pose_offset = counter(free_poses, &mut n, 6);
                group_offset = group_offsets(&group_free, &mut n);
                bias_offset = counter(p.prior_offsets.iter().map(|o| !o.fixed), &mut n, 3);
                // Ends of scale bars couple two points, so they stay in the reduced system.
                let mut on_bar = vec![false; p.points.len()];
                for bar in &p.scale_bars {
                    on_bar[bar.a] = true;
                    on_bar[bar.b] = true;
                }
                let free: Vec<bool> = free_points.collect();
                point_offset = counter(free.iter().zip(&on_bar).map(|(f, b)| *f && *b), &mut n, 3);
                point_index = counter(free.iter().zip(&on_bar).map(|(f, b)| *f && !*b), &mut m, 1);
                pose_index = none_i;
            }
            Eliminate::Poses => {
                point_offset = counter(free_points, &mut n, 3);
                let none_p = vec![None; p.points.len()];
                group_offset = group_offsets(&group_free, &mut n);
                bias_offset = counter(p.prior_offsets.iter().map(|o| !o.fixed), &mut n, 3);
                pose_index = counter(free_poses, &mut m, 1);
                pose_offset = none_i;
                point_index = none_p;
            }
        }
        Layout {
            eliminate,
            pose_offset,
            group_offset,
            bias_offset,
            group_free,
            point_offset,
            point_index,
            pose_index,
            num_camera_params: n,
            num_free_points: m,
        }
    }

    /// The reduced-side parameter blocks of the iterative solver's preconditioner, as column
    /// lists: each pose (with its camera group's intrinsics when no other image shares them, as in
    /// BAL's per-camera intrinsics), each point, each shared group's intrinsics.
    pub(crate) fn parameter_blocks(&self, p: &BundleProblem) -> Vec<Vec<usize>> {
        let mut users = vec![0usize; p.groups.len()];
        for (i, im) in p.images.iter().enumerate() {
            if self.pose_offset[i].is_some() {
                users[im.group] += 1;
            }
        }
        let group_cols = |g: usize| -> Vec<usize> {
            self.group_offset[g].map_or(Vec::new(), |o| (o..o + self.group_free[g].len()).collect())
        };
        let mut merged = vec![false; p.groups.len()];
        let mut blocks = Vec::new();
        for (i, off) in self.pose_offset.iter().enumerate() {
            if let Some(o) = off {
                let mut cols: Vec<usize> = (*o..o + 6).collect();
                let g = p.images[i].group;
                if users[g] == 1 {
                    cols.extend(group_cols(g));
                    merged[g] = true;
                }
                blocks.push(cols);
            }
        }
        for o in self.point_offset.iter().flatten() {
            blocks.push((*o..o + 3).collect());
        }
        for g in 0..p.groups.len() {
            let cols = group_cols(g);
            if !merged[g] && !cols.is_empty() {
                blocks.push(cols);
            }
        }
        for o in self.bias_offset.iter().flatten() {
            blocks.push((*o..o + 3).collect());
        }
        blocks
    }

    /// The eliminated block an observation of `image` and `point` belongs to.
    pub(crate) fn eliminated(&self, image: usize, point: usize) -> Option<usize> {
        match self.eliminate {
            Eliminate::Points => self.point_index[point],
            Eliminate::Poses => self.pose_index[image],
        }
    }

    /// How many reduced-side columns an observation has ([`Self::observation_columns`]'s
    /// length), without listing them.
    pub(crate) fn observation_column_count(
        &self,
        p: &BundleProblem,
        image: usize,
        point: usize,
    ) -> usize {
        let g = p.images[image].group;
        6 * usize::from(self.pose_offset[image].is_some())
            + 3 * usize::from(self.point_offset[point].is_some())
            + self.group_offset[g].map_or(0, |_| self.group_free[g].len())
    }

    /// Reduced-side columns of an observation.
    pub(crate) fn observation_columns(
        &self,
        p: &BundleProblem,
        image: usize,
        point: usize,
    ) -> Vec<usize> {
        let mut cols = Vec::new();
        self.extend_observation_columns(p, image, point, &mut cols);
        cols
    }

    /// Appends an observation's reduced-side columns to `cols`: its pose's, its point's, its
    /// group's free intrinsics (the order of its Jacobian's columns in the linearisation).
    pub(crate) fn extend_observation_columns(
        &self,
        p: &BundleProblem,
        image: usize,
        point: usize,
        cols: &mut Vec<usize>,
    ) {
        if let Some(off) = self.pose_offset[image] {
            cols.extend(off..off + 6);
        }
        if let Some(off) = self.point_offset[point] {
            cols.extend(off..off + 3);
        }
        let g = p.images[image].group;
        if let Some(off) = self.group_offset[g] {
            cols.extend(off..off + self.group_free[g].len());
        }
    }
}
