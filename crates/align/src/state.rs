//! The state of one incremental reconstruction: the block so far, which track became which point,
//! and the operations on points that every phase uses (triangulate a track, extend a point with
//! newly oriented images, drop bad observations).

use nalgebra::Vector3;
use timesift_core::{Pose, TrackElement, project_world};
use timesift_geometry::triangulation::{triangulate_dlt, triangulation_angle};

use crate::model::{Reconstruction, SfmInput, SparsePoint};
use crate::options::{OutlierBound, SfmOptions};

/// Standard deviations of the reprojection error beyond which an observation is an outlier
/// ([`State::tighten_to_noise`]).
const OUTLIER_SIGMAS: f64 = 4.0;
/// The outlier bound never goes below this (noise-free synthetic blocks have σ ≈ 0).
const MIN_OUTLIER_BOUND_PX: f64 = 0.5;
/// Observations needed to estimate the noise.
const MIN_OBSERVATIONS_FOR_NOISE: usize = 100;

/// "No track" / "no point" in the index tables.
pub(crate) const NONE: u32 = u32::MAX;

/// Per image, per keypoint: the index of its track, or [`NONE`].
pub(crate) fn track_table(input: &SfmInput) -> Vec<Vec<u32>> {
    let mut table: Vec<Vec<u32>> = input
        .images
        .iter()
        .map(|im| vec![NONE; im.keypoints.len()])
        .collect();
    for (t, track) in input.tracks.iter().enumerate() {
        for e in &track.elements {
            table[e.image.index()][e.feature.index()] = t as u32;
        }
    }
    table
}

/// One reconstruction in progress.
pub(crate) struct State<'a> {
    pub input: &'a SfmInput,
    pub options: &'a SfmOptions,
    pub track_of: &'a [Vec<u32>],
    pub rec: Reconstruction,
    /// Per track: its point, or [`NONE`].
    pub point_of_track: Vec<u32>,
    /// The image whose pose holds the datum when nothing else does (no fixed image, no prior).
    pub gauge: usize,
    /// Images this reconstruction may orient (not taken by an earlier component).
    pub available: Vec<bool>,
    /// Failed orientation attempts per image since the last global adjustment.
    pub failed_trials: Vec<usize>,
    /// Largest reprojection error of a kept observation, pixels: the options' threshold, or
    /// the block's own outlier bound once it is adjusted ([`State::tighten_to_noise`]).
    pub max_error_px: f64,
    /// Per camera group, its own outlier bound once the block is adjusted
    /// ([`State::tighten_to_noise`]); empty before, and then [`State::max_error_px`] holds.
    pub group_bound_px: Vec<f64>,
    /// Current values of the GNSS offsets of the adjustments (see [`crate::adjust::OffsetPrior`]).
    pub offsets: Vec<nalgebra::Vector3<f64>>,
}

impl<'a> State<'a> {
    pub fn new(
        input: &'a SfmInput,
        options: &'a SfmOptions,
        track_of: &'a [Vec<u32>],
        available: Vec<bool>,
    ) -> Self {
        State {
            input,
            options,
            track_of,
            rec: Reconstruction {
                cameras: input.cameras.clone(),
                poses: vec![None; input.images.len()],
                points: Vec::new(),
            },
            point_of_track: vec![NONE; input.tracks.len()],
            gauge: 0,
            available,
            failed_trials: vec![0; input.images.len()],
            max_error_px: options.max_reprojection_px,
            group_bound_px: Vec::new(),
            offsets: Vec::new(),
        }
    }

    /// Largest reprojection error of a kept observation of `e`'s image, pixels: its camera
    /// group's own bound once there is one, the block's otherwise.
    pub fn bound_of(&self, e: &TrackElement) -> f64 {
        self.group_bound_px
            .get(self.input.images[e.image.index()].group)
            .copied()
            .unwrap_or(self.max_error_px)
    }

    /// Reprojection error of a world point in an oriented image, pixels (infinite when it does
    /// not project or the image is not oriented).
    pub fn error(&self, position: &Vector3<f64>, e: &TrackElement) -> f64 {
        let image = e.image.index();
        let Some(pose) = self.rec.poses[image] else {
            return f64::INFINITY;
        };
        if pose.transform_point(position).z <= 0.0 {
            return f64::INFINITY;
        }
        let camera = self.rec.camera_of(self.input, image);
        project_world(camera, &pose, position)
            .map_or(f64::INFINITY, |u| (u - self.input.pixel(e)).norm())
    }

    /// Largest angle between the rays of any two observations, degrees.
    pub fn max_angle_deg(&self, position: &Vector3<f64>, observations: &[TrackElement]) -> f64 {
        let centres: Vec<Vector3<f64>> = observations
            .iter()
            .filter_map(|e| self.rec.poses[e.image.index()].map(|p| p.center()))
            .collect();
        let mut best: f64 = 0.0;
        for (i, a) in centres.iter().enumerate() {
            for b in &centres[i + 1..] {
                best = best.max(triangulation_angle(a, b, position));
            }
        }
        best.to_degrees()
    }

    /// Triangulates a track without a point from its elements in oriented images: DLT, then the
    /// worst observation is dropped while any exceeds the reprojection threshold; the point is
    /// kept when at least two observations remain, in front of their cameras, with enough
    /// triangulation angle. Returns whether a point was made.
    pub fn triangulate_track(&mut self, track: usize) -> bool {
        if self.point_of_track[track] != NONE {
            return false;
        }
        let mut elements: Vec<TrackElement> = self.input.tracks[track]
            .elements
            .iter()
            .filter(|e| self.rec.poses[e.image.index()].is_some())
            .copied()
            .collect();
        let mut views: Vec<(Pose, Vector3<f64>)> = Vec::with_capacity(elements.len());
        loop {
            if elements.len() < 2 {
                return false;
            }
            let Some(position) = self.triangulate_elements(&elements, &mut views) else {
                return false;
            };
            // Errors in units of each observation's bound (groups may differ).
            let errors: Vec<f64> = elements
                .iter()
                .map(|e| self.error(&position, e) / self.bound_of(e))
                .collect();
            let (worst, worst_error) = errors
                .iter()
                .copied()
                .enumerate()
                .fold((0, 0.0), |b, (i, e)| if e > b.1 { (i, e) } else { b });
            if worst_error > 1.0 {
                elements.remove(worst);
                continue;
            }
            if self.max_angle_deg(&position, &elements) < self.options.min_triangulation_angle_deg {
                return false;
            }
            self.point_of_track[track] = self.rec.points.len() as u32;
            self.rec.points.push(SparsePoint {
                position,
                track,
                observations: elements,
            });
            return true;
        }
    }

    /// DLT triangulation of observations in oriented images (`views` is scratch space).
    pub fn triangulate_elements(
        &self,
        elements: &[TrackElement],
        views: &mut Vec<(Pose, Vector3<f64>)>,
    ) -> Option<Vector3<f64>> {
        views.clear();
        for e in elements {
            let image = e.image.index();
            let camera = self.rec.camera_of(self.input, image);
            let ray = camera.unproject(&self.input.pixel(e)).ok()?;
            views.push((self.rec.poses[image]?, ray));
        }
        triangulate_dlt(views).ok()
    }

    /// Adds to the track's point, or triangulates, every element in an oriented image that is
    /// not yet an observation and reprojects within the threshold. Returns observations added.
    pub fn complete_track(&mut self, track: usize) -> usize {
        let p = self.point_of_track[track];
        if p == NONE {
            return if self.triangulate_track(track) {
                self.rec.points[self.point_of_track[track] as usize]
                    .observations
                    .len()
            } else {
                0
            };
        }
        let point = &self.rec.points[p as usize];
        let missing: Vec<TrackElement> = self.input.tracks[track]
            .elements
            .iter()
            .filter(|e| {
                self.rec.poses[e.image.index()].is_some()
                    && !point.observations.contains(e)
                    && self.error(&point.position, e) <= self.bound_of(e)
            })
            .copied()
            .collect();
        let added = missing.len();
        if added > 0 {
            let point = &mut self.rec.points[p as usize];
            point.observations.extend(missing);
            point.observations.sort();
        }
        added
    }

    /// Completes every track with a keypoint in `image`.
    pub fn complete_tracks_of_image(&mut self, image: usize) -> usize {
        let tracks: Vec<u32> = self.track_of[image]
            .iter()
            .copied()
            .filter(|&t| t != NONE)
            .collect();
        tracks
            .into_iter()
            .map(|t| self.complete_track(t as usize))
            .sum()
    }

    /// Completes every track.
    pub fn complete_all_tracks(&mut self) -> usize {
        (0..self.input.tracks.len())
            .map(|t| self.complete_track(t))
            .sum()
    }

    /// Drops observations beyond the reprojection threshold from the given points, then the
    /// points left with fewer than two observations or too small an angle. Returns the number of
    /// observations dropped (those of dropped points included).
    pub fn filter_points(&mut self, points: &[usize]) -> usize {
        let mut dropped = 0;
        for &p in points {
            let point = &self.rec.points[p];
            if point.observations.is_empty() {
                continue;
            }
            let keep: Vec<TrackElement> = point
                .observations
                .iter()
                .filter(|e| self.error(&point.position, e) <= self.bound_of(e))
                .copied()
                .collect();
            let angle_ok = keep.len() >= 2
                && self.max_angle_deg(&point.position, &keep)
                    >= self.options.min_triangulation_angle_deg;
            let before = point.observations.len();
            if angle_ok {
                dropped += before - keep.len();
                self.rec.points[p].observations = keep;
            } else {
                dropped += before;
                self.kill_point(p);
            }
        }
        dropped
    }

    /// Removes a point (its slot stays, empty, until [`State::compact`]).
    pub fn kill_point(&mut self, p: usize) {
        let point = &mut self.rec.points[p];
        point.observations.clear();
        self.point_of_track[point.track] = NONE;
    }

    /// Indices of the live points.
    pub fn live_points(&self) -> Vec<usize> {
        (0..self.rec.points.len())
            .filter(|&p| !self.rec.points[p].observations.is_empty())
            .collect()
    }

    /// Indices of the live points observed by any of `images`.
    pub fn points_seen_by(&self, images: &[usize]) -> Vec<usize> {
        let mut points: Vec<usize> = images
            .iter()
            .flat_map(|&i| {
                self.track_of[i].iter().filter_map(|&t| {
                    if t == NONE {
                        return None;
                    }
                    let p = self.point_of_track[t as usize];
                    (p != NONE).then_some(p as usize)
                })
            })
            .filter(|&p| {
                self.rec.points[p]
                    .observations
                    .iter()
                    .any(|e| images.contains(&e.image.index()))
            })
            .collect();
        points.sort_unstable();
        points.dedup();
        points
    }

    /// Drops the empty point slots, renumbering the rest.
    pub fn compact(&mut self) {
        self.rec.points.retain(|p| !p.observations.is_empty());
        self.point_of_track.fill(NONE);
        for (p, point) in self.rec.points.iter().enumerate() {
            self.point_of_track[point.track] = p as u32;
        }
    }

    /// Lowers the observation threshold to `OUTLIER_SIGMAS` standard deviations of the
    /// reprojection errors (never above the options' threshold): a 2-D Gaussian error exceeds
    /// it once in 3000 observations, so what it removes is mismatches that the fixed threshold
    /// let through (grain matched to grain, a moving shadow edge). σ is estimated robustly from
    /// the median error norm (Rayleigh: median = 1.1774 σ), per camera group from its own
    /// observations: a noisier group (scanned film among digital images) keeps what its own
    /// noise allows instead of the block's pooled bound. A group with too few observations
    /// takes the pooled bound. Returns the pooled bound.
    pub fn tighten_to_noise(&mut self) -> f64 {
        let bound = |median: f64| {
            (OUTLIER_SIGMAS * median / 1.1774)
                .max(MIN_OUTLIER_BOUND_PX)
                .min(self.options.max_reprojection_px)
        };
        if let Some((median, MIN_OBSERVATIONS_FOR_NOISE..)) = self.median_error() {
            self.max_error_px = bound(median);
        }
        self.group_bound_px = match self.options.outlier_bound {
            OutlierBound::PerGroup => self
                .group_noise()
                .iter()
                .map(|n| match n {
                    Some((median, MIN_OBSERVATIONS_FOR_NOISE..)) => bound(*median),
                    _ => self.max_error_px,
                })
                .collect(),
            OutlierBound::Pooled => vec![self.max_error_px; self.input.cameras.len()],
        };
        self.max_error_px
    }

    /// Per camera group: the median reprojection error of its observations, pixels, and how
    /// many finite errors it is taken over.
    pub fn group_noise(&self) -> Vec<Option<(f64, usize)>> {
        let mut errors: Vec<Vec<f64>> = vec![Vec::new(); self.input.cameras.len()];
        for p in &self.rec.points {
            for e in &p.observations {
                let error = self.error(&p.position, e);
                if error.is_finite() {
                    errors[self.input.images[e.image.index()].group].push(error);
                }
            }
        }
        errors
            .into_iter()
            .map(|mut errors| {
                if errors.is_empty() {
                    return None;
                }
                let mid = errors.len() / 2;
                let (_, median, _) = errors.select_nth_unstable_by(mid, f64::total_cmp);
                Some((*median, errors.len()))
            })
            .collect()
    }

    /// Median reprojection error of the points' observations, pixels, and how many finite
    /// errors it is taken over; `None` without any.
    pub fn median_error(&self) -> Option<(f64, usize)> {
        let mut errors: Vec<f64> = self
            .rec
            .points
            .iter()
            .flat_map(|p| p.observations.iter().map(|e| self.error(&p.position, e)))
            .filter(|e| e.is_finite())
            .collect();
        if errors.is_empty() {
            return None;
        }
        let mid = errors.len() / 2;
        let (_, median, _) = errors.select_nth_unstable_by(mid, f64::total_cmp);
        Some((*median, errors.len()))
    }

    /// Oriented images.
    pub fn oriented(&self) -> Vec<usize> {
        (0..self.rec.poses.len())
            .filter(|&i| self.rec.poses[i].is_some())
            .collect()
    }
}

impl<'a> State<'a> {
    /// A state over a finished reconstruction (for adjustments after georeferencing).
    pub fn with_reconstruction(
        input: &'a SfmInput,
        options: &'a SfmOptions,
        track_of: &'a [Vec<u32>],
        rec: Reconstruction,
    ) -> Self {
        let mut state = State::new(input, options, track_of, vec![true; input.images.len()]);
        state.gauge = rec.poses.iter().position(Option::is_some).unwrap_or(0);
        state.rec = rec;
        state.compact();
        state
    }
}
