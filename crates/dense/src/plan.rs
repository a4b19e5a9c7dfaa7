//! What dense matching of one epoch will do before it touches a pixel: each view's working camera,
//! its pose in a local frame, its source views and its depth range, all from the frozen
//! orientation and the sparse points.
//!
//! Source views (per reference view, from the same epoch only — the caller passes one epoch):
//! every other view is scored as OpenMVS does, per shared sparse point, by a triangulation-angle
//! weight (full between 5° and 45°, penalised below and above) times a scale weight (the ratio
//! of the two views' ground footprints, full between 1 and 1.6), the sum multiplied by the
//! fraction of the reference image those points cover (16 × 16 cells). Besides the shared tie
//! points, a 16 × 16 grid of the reference's rays at the median depth of its sparse points
//! counts as points seen by every view they project into: blocks with few tie points between
//! neighbours (film scans) keep every overlapping neighbour.
//! Views with fewer than 3 shared points or whose 75th-percentile triangulation angle is below
//! 1° (COLMAP's rule) are never sources. Of the others, at most `max_sources` are kept: first,
//! in score order, those that see a part of the reference's field (a coverage cell) that the
//! ones kept so far leave without a source, then without a second, a third; then the best of
//! the rest whose score is at least 3 % of the best. By score alone the views that see a
//! reference's borders (the block's edge, an oblique, the strip's next-but-one image) would
//! often be left out, and those borders get no depth. Filtering and fusion check a view's depths
//! against more views than its sources: the others that score at least 3 % of the best, best
//! first, up to twice `max_sources` in all.
//!
//! Depth range (COLMAP's rule, over more points): the 1st and 99th percentiles of the depths of
//! the sparse points in the view's field — its own and those of its co-visible views that
//! project into its image —, widened by 25 %.

use nalgebra::{Translation3, UnitQuaternion, Vector3};
use timesift_core::{Camera, Pose};

use crate::DenseError;
use crate::camera::WorkingCamera;
use crate::undistort::working_camera;

/// One oriented view of the epoch: its camera (original, distorted) and `cam_from_world`.
#[derive(Debug, Clone, PartialEq)]
pub struct View {
    /// The camera model of the original image.
    pub camera: Camera,
    /// The frozen orientation.
    pub cam_from_world: Pose,
}

/// A sparse (tie) point and the views that observe it (indices into the epoch's views).
#[derive(Debug, Clone, PartialEq)]
pub struct SparsePoint {
    /// World position.
    pub position: Vector3<f64>,
    /// Observing views, indices into [`EpochInput::views`].
    pub views: Vec<usize>,
}

/// The orientation of one epoch, frozen: what dense matching starts from.
#[derive(Debug, Clone, PartialEq)]
pub struct EpochInput {
    /// Oriented views.
    pub views: Vec<View>,
    /// Sparse points observed by at least one of them.
    pub points: Vec<SparsePoint>,
}

/// Options of the plan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanOptions {
    /// Resolution level: 1 (full), 2 (half), 4 or 8.
    pub level: u32,
    /// Most source views per reference view.
    pub max_sources: usize,
    /// Whether to match again at half the level (twice the resolution) where matching at the
    /// level is poor (see [`crate::patchmatch::refine`]). The working images are then made at
    /// half the level; at level 1 there is no finer resolution and this does nothing.
    pub refine: bool,
}

impl Default for PlanOptions {
    fn default() -> Self {
        PlanOptions {
            level: 2,
            max_sources: 8,
            refine: true,
        }
    }
}

/// A source view of a reference view, with its score.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Source {
    /// Index of the source view in the epoch.
    pub view: usize,
    /// View-selection score (higher is better).
    pub score: f64,
    /// Shared sparse points.
    pub shared_points: usize,
    /// Median triangulation angle over the shared points, radians.
    pub median_angle: f64,
}

/// Everything dense matching needs to know about one view.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewPlan {
    /// The ideal pinhole the image is resampled to.
    pub camera: WorkingCamera,
    /// Pose in the plan's local frame (world minus [`EpochPlan::origin`]).
    pub cam_from_local: Pose,
    /// Source views, best first; empty when no view qualifies (the view gets no depth map).
    pub sources: Vec<Source>,
    /// The views whose depth maps are checked against this one's (filtering, fusion): its
    /// sources, then the other views that overlap it (best-scored first, up to twice
    /// `max_sources` with the sources), then every view that names it so. Symmetric, so that
    /// two views that match each other in one direction only still confirm each other's
    /// depths. Wider than the sources: where few views see a part of the field (a block's
    /// edge), a depth confirmed by a view that was not a source there still makes a point.
    pub neighbours: Vec<usize>,
    /// Depth range (min, max), metres along the optical axis.
    pub depth_range: (f64, f64),
}

/// The plan of one epoch.
#[derive(Debug, Clone, PartialEq)]
pub struct EpochPlan {
    /// World position of the local frame's origin (the mean camera centre), so that matching
    /// works with small numbers whatever the CRS.
    pub origin: Vector3<f64>,
    /// Per view, in the order of [`EpochInput::views`].
    pub views: Vec<ViewPlan>,
    /// The level of the working cameras: the requested level, or half of it when refining.
    pub level: u32,
    /// The finest pyramid scales matched only where the coarser one is poor: 1 when the plan
    /// refines (the requested level is pyramid scale 1 of the working images), else 0.
    pub refined_scales: usize,
}

impl EpochPlan {
    /// `local_from_world` for points.
    pub fn local_from_world(&self, p: &Vector3<f64>) -> Vector3<f64> {
        p - self.origin
    }
    /// `world_from_local` for points.
    pub fn world_from_local(&self, p: &Vector3<f64>) -> Vector3<f64> {
        p + self.origin
    }
}

/// Least shared points for a view to be a source.
const MIN_SHARED_POINTS: usize = 3;
/// Least 75th-percentile triangulation angle of a source (COLMAP's `min_triangulation_angle`).
const MIN_SOURCE_ANGLE_DEG: f64 = 1.0;
/// Triangulation angles with full weight.
const GOOD_ANGLES_DEG: (f64, f64) = (5.0, 45.0);
/// Footprint ratios with full weight (OpenMVS).
const GOOD_SCALE_RATIO: f64 = 1.6;
/// Least score relative to the best of a source chosen for its score rather than for the part
/// of the field it covers, and of an overlapping view that filtering and fusion check against.
const MIN_RELATIVE_SCORE: f64 = 0.03;
/// Coverage grid of the reference image (cells per side).
const COVERAGE_CELLS: usize = 16;
/// Percentiles and widening of the depth range.
const DEPTH_PERCENTILES: (f64, f64) = (0.01, 0.99);
const DEPTH_MARGIN: (f64, f64) = (0.75, 1.25);
/// Least sparse points in front of a view to bound its depths.
const MIN_DEPTH_POINTS: usize = 3;

/// Weight of a triangulation angle (radians): 1 between 5° and 45°, falling quadratically to 0
/// at 0°, and as a Gaussian of σ 10° beyond 45°.
fn angle_weight(angle: f64) -> f64 {
    let (lo, hi) = (
        GOOD_ANGLES_DEG.0.to_radians(),
        GOOD_ANGLES_DEG.1.to_radians(),
    );
    if angle < lo {
        (angle / lo).powi(2)
    } else if angle <= hi {
        1.0
    } else {
        let s = 10f64.to_radians();
        (-(angle - hi).powi(2) / (2.0 * s * s)).exp()
    }
}

/// Weight of a footprint ratio `reference / source` (OpenMVS): sources seeing the ground at a
/// much finer or coarser resolution than the reference match badly.
fn scale_weight(ratio: f64) -> f64 {
    if ratio > GOOD_SCALE_RATIO {
        (GOOD_SCALE_RATIO / ratio).powi(2)
    } else if ratio >= 1.0 {
        1.0
    } else {
        ratio * ratio
    }
}

/// The plan of one epoch.
pub fn plan_epoch(input: &EpochInput, options: &PlanOptions) -> Result<EpochPlan, DenseError> {
    check_epoch_input(input, options)?;
    let n = input.views.len();
    let origin = input
        .views
        .iter()
        .map(|v| v.cam_from_world.center())
        .sum::<Vector3<f64>>()
        / n as f64;
    let world_from_local = Pose::new(
        UnitQuaternion::identity(),
        Translation3::from(origin).vector,
    );
    let poses: Vec<Pose> = input
        .views
        .iter()
        .map(|v| v.cam_from_world * world_from_local)
        .collect();
    let centres: Vec<Vector3<f64>> = poses.iter().map(Pose::center).collect();
    let refined_scales = usize::from(options.refine && options.level > 1);
    let level = options.level >> refined_scales;
    let cameras = input
        .views
        .iter()
        .map(|v| working_camera(&v.camera, level))
        .collect::<Result<Vec<_>, _>>()?;
    let points: Vec<Vector3<f64>> = input.points.iter().map(|p| p.position - origin).collect();
    // Points of each view.
    let mut points_of: Vec<Vec<usize>> = vec![Vec::new(); n];
    for (k, p) in input.points.iter().enumerate() {
        for &v in &p.views {
            if points_of[v].last() != Some(&k) {
                points_of[v].push(k);
            }
        }
    }
    let views = (0..n)
        .map(|a| {
            let field = field_points(
                a,
                &points_of,
                &input.points,
                &poses[a],
                &cameras[a],
                &points,
            );
            let (depth_range, median_depth) = depth_range(a, &poses[a], &field, &points)?;
            let (sources, overlapping) = select_sources(
                a,
                input,
                &poses,
                &centres,
                &cameras,
                &points,
                median_depth,
                options,
            );
            // The views checked against this one: its sources, then the other views that
            // qualify, best first, up to twice `max_sources` in all.
            let mut links: Vec<usize> = sources.iter().map(|s| s.view).collect();
            let room = (2 * options.max_sources).saturating_sub(links.len());
            links.extend(overlapping.into_iter().take(room));
            Ok(ViewPlan {
                camera: cameras[a],
                cam_from_local: poses[a],
                sources,
                neighbours: links,
                depth_range,
            })
        })
        .collect::<Result<Vec<_>, DenseError>>()?;
    let mut views = views;
    link_both_ways(&mut views);
    Ok(EpochPlan {
        origin,
        views,
        level,
        refined_scales,
    })
}

/// At least two views, at least one source per view, and sparse points that name views of the
/// epoch.
fn check_epoch_input(input: &EpochInput, options: &PlanOptions) -> Result<(), DenseError> {
    let n = input.views.len();
    if n < 2 {
        return Err(DenseError::TooFewViews {
            found: n,
            needed: 2,
        });
    }
    if options.max_sources == 0 {
        return Err(DenseError::InvalidOption(
            "max_sources = 0: expected at least 1".into(),
        ));
    }
    for p in &input.points {
        if let Some(&v) = p.views.iter().find(|&&v| v >= n) {
            return Err(DenseError::InvalidInput(format!(
                "a sparse point names view {v} of an epoch of {n} views"
            )));
        }
    }
    Ok(())
}

/// Adds to each view's neighbours the views that name it as theirs (after its own, in view
/// order), so that fusion checks every pair from both sides.
fn link_both_ways(views: &mut [ViewPlan]) {
    let mut reverse: Vec<Vec<usize>> = vec![Vec::new(); views.len()];
    for (a, v) in views.iter().enumerate() {
        for &b in &v.neighbours {
            reverse[b].push(a);
        }
    }
    for (a, v) in views.iter_mut().enumerate() {
        for &b in &reverse[a] {
            if !v.neighbours.contains(&b) {
                v.neighbours.push(b);
            }
        }
    }
}

/// The sparse points in view `a`'s field: its own, and those of the views that share a point
/// with it which project into its image in front of it. An oblique view's own tie points may
/// all lie in the near part of its field; its neighbours' reach the far part.
fn field_points(
    a: usize,
    points_of: &[Vec<usize>],
    sparse: &[SparsePoint],
    pose: &Pose,
    camera: &WorkingCamera,
    points: &[Vector3<f64>],
) -> Vec<usize> {
    let mut covisible: Vec<usize> = points_of[a]
        .iter()
        .flat_map(|&k| sparse[k].views.iter().copied())
        .collect();
    covisible.sort_unstable();
    covisible.dedup();
    let mut field: Vec<usize> = covisible
        .iter()
        .flat_map(|&b| points_of[b].iter().copied())
        .filter(|&k| {
            camera
                .project(&pose.transform_point(&points[k]))
                .is_some_and(|p| camera.contains(p.x, p.y))
        })
        .chain(points_of[a].iter().copied())
        .collect();
    field.sort_unstable();
    field.dedup();
    field
}

fn depth_range(
    view: usize,
    pose: &Pose,
    point_ids: &[usize],
    points: &[Vector3<f64>],
) -> Result<((f64, f64), f64), DenseError> {
    let mut depths: Vec<f64> = point_ids
        .iter()
        .map(|&k| pose.transform_point(&points[k]).z)
        .filter(|z| *z > 0.0)
        .collect();
    if depths.len() < MIN_DEPTH_POINTS {
        return Err(DenseError::NoDepthRange {
            view,
            points: depths.len(),
        });
    }
    depths.sort_by(f64::total_cmp);
    let at = |q: f64| depths[((depths.len() as f64 * q) as usize).min(depths.len() - 1)];
    Ok((
        (
            at(DEPTH_PERCENTILES.0) * DEPTH_MARGIN.0,
            at(DEPTH_PERCENTILES.1) * DEPTH_MARGIN.1,
        ),
        at(0.5),
    ))
}

/// Per candidate source: score sum, shared points, angles, coverage cells.
struct Candidate {
    score: f64,
    angles: Vec<f64>,
    cells: Vec<bool>,
}

/// Samples of the reference image's field for the overlap term: a grid of this many rays per
/// side, at the median depth of the view's sparse points.
const OVERLAP_SAMPLES: usize = 16;

/// The sources of view `a` (at most `max_sources`, best score first), and the other views that
/// qualify as sources, best first: they overlap `a`, for filtering and fusion.
#[allow(clippy::too_many_arguments)]
fn select_sources(
    a: usize,
    input: &EpochInput,
    poses: &[Pose],
    centres: &[Vector3<f64>],
    cameras: &[WorkingCamera],
    points: &[Vector3<f64>],
    median_depth: f64,
    options: &PlanOptions,
) -> (Vec<Source>, Vec<usize>) {
    let n = input.views.len();
    let mut candidates: Vec<Option<Candidate>> = (0..n).map(|_| None).collect();
    let cam_a = &cameras[a];
    let local_from_a = poses[a].inverse();
    // One observation of local point `x` by view `b` besides `a`.
    let mut observe = |b: usize, x: &Vector3<f64>, cell: Option<usize>| {
        let in_a = poses[a].transform_point(x);
        let in_b = poses[b].transform_point(x);
        if !(in_b.z > 0.0) || !(in_a.z > 0.0) {
            return;
        }
        let angle = (centres[a] - x).angle(&(centres[b] - x));
        // Footprint of a pixel on the surface: depth / focal.
        let ratio = (in_b.z / cameras[b].f) / (in_a.z / cam_a.f);
        let c = candidates[b].get_or_insert_with(|| Candidate {
            score: 0.0,
            angles: Vec::new(),
            cells: vec![false; COVERAGE_CELLS * COVERAGE_CELLS],
        });
        // The footprint ratio as OpenMVS defines it: reference over source resolution.
        c.score += angle_weight(angle).max(0.1) * scale_weight(1.0 / ratio);
        c.angles.push(angle);
        if let Some(cell) = cell {
            c.cells[cell] = true;
        }
    };
    let cell_of = |u: f64, v: f64| -> Option<usize> {
        if !cam_a.contains(u, v) {
            return None;
        }
        let ci = (u / cam_a.width as f64 * COVERAGE_CELLS as f64) as usize;
        let cj = (v / cam_a.height as f64 * COVERAGE_CELLS as f64) as usize;
        Some(cj.min(COVERAGE_CELLS - 1) * COVERAGE_CELLS + ci.min(COVERAGE_CELLS - 1))
    };
    // Shared sparse points.
    for (k, p) in input.points.iter().enumerate() {
        if !p.views.contains(&a) {
            continue;
        }
        let x = &points[k];
        let Some(pixel) = cam_a.project(&poses[a].transform_point(x)) else {
            continue;
        };
        let cell = cell_of(pixel.x, pixel.y);
        for &b in p.views.iter().filter(|&&b| b != a) {
            observe(b, x, cell);
        }
    }
    // Overlap: the reference's field at its median depth, seen by the other views. Blocks with
    // few tie points (film scans decades apart) still find every overlapping neighbour.
    for j in 0..OVERLAP_SAMPLES {
        for i in 0..OVERLAP_SAMPLES {
            let u = (i as f64 + 0.5) / OVERLAP_SAMPLES as f64 * cam_a.width as f64;
            let v = (j as f64 + 0.5) / OVERLAP_SAMPLES as f64 * cam_a.height as f64;
            let x = local_from_a.transform_point(&(cam_a.ray(u, v) * median_depth));
            for b in (0..n).filter(|&b| b != a) {
                let seen = cameras[b]
                    .project(&poses[b].transform_point(&x))
                    .is_some_and(|p| cameras[b].contains(p.x, p.y));
                if seen {
                    observe(b, &x, cell_of(u, v));
                }
            }
        }
    }
    let mut ranked = ranked_sources(candidates);
    let best = ranked.first().map_or(0.0, |s| s.0.score);
    let floor = MIN_RELATIVE_SCORE * best;
    let sources = choose_covering(&ranked, options.max_sources, floor);
    ranked.retain(|s| s.0.score >= floor);
    let overlapping = ranked
        .iter()
        .map(|(s, _)| s.view)
        .filter(|v| !sources.iter().any(|s| s.view == *v))
        .collect();
    (sources, overlapping)
}

/// The candidates that qualify as sources (enough shared points, a wide enough angle), each
/// with its coverage cells, best score first (then by view).
fn ranked_sources(candidates: Vec<Option<Candidate>>) -> Vec<(Source, Vec<bool>)> {
    let mut ranked: Vec<(Source, Vec<bool>)> = candidates
        .into_iter()
        .enumerate()
        .filter_map(|(b, c)| {
            let mut c = c?;
            if c.angles.len() < MIN_SHARED_POINTS {
                return None;
            }
            c.angles.sort_by(f64::total_cmp);
            let q = |f: f64| c.angles[((c.angles.len() - 1) as f64 * f).round() as usize];
            if q(0.75) < MIN_SOURCE_ANGLE_DEG.to_radians() {
                return None;
            }
            let area = c.cells.iter().filter(|&&x| x).count() as f64 / c.cells.len() as f64;
            let source = Source {
                view: b,
                score: c.score * area.max(0.01),
                shared_points: c.angles.len(),
                median_angle: q(0.5),
            };
            Some((source, c.cells))
        })
        .collect();
    ranked.sort_by(|x, y| {
        y.0.score
            .total_cmp(&x.0.score)
            .then(x.0.view.cmp(&y.0.view))
    });
    ranked
}

/// Sources that see a part of the reference's field, wanted for every part that enough
/// candidates see: fusion keeps a point that the reference and two sources agree on, and one
/// more stands in where one of them fails (a grazing or a much coarser view).
const COVERING_SOURCES: usize = 3;

/// Chooses at most `max` of the `ranked` candidates (best score first, each with the
/// reference's coverage cells it sees), keeping that order.
///
/// The best-scored views all look at the middle of the reference's field, where most tie points
/// are; taken by score alone, the few views that see its borders (the edge of the block, a
/// neighbouring strip's margin, an oblique) can all fall beyond `max`, and then those parts of
/// the field have no source and no depth. So the candidates are walked in score order once per
/// depth of cover, 1 to [`COVERING_SOURCES`]: a candidate is chosen when it sees a cell with
/// fewer chosen sources than that depth (and than the candidates can give the cell). The
/// best-scored of the others whose score is at least `fill_floor` then fill what is left.
///
/// The covering walk has no score floor: a view that overlaps the reference by a sixth at a
/// wide angle (the next-but-one image of a strip of film scans at 60 % overlap, few tie points)
/// scores about 2 % of the best neighbour, yet it is the third view of that sixth of the field,
/// without which fusion has no point there.
fn choose_covering(ranked: &[(Source, Vec<bool>)], max: usize, fill_floor: f64) -> Vec<Source> {
    let cells = ranked.first().map_or(0, |c| c.1.len());
    let mut seen_by = vec![0usize; cells];
    for (_, seen) in ranked {
        for (n, &s) in seen_by.iter_mut().zip(seen) {
            *n += usize::from(s);
        }
    }
    let mut chosen = vec![false; ranked.len()];
    let mut count = 0;
    let mut cover = vec![0usize; cells];
    for depth in 1..=COVERING_SOURCES {
        for (k, (_, seen)) in ranked.iter().enumerate() {
            if count == max {
                break;
            }
            let lifts = (0..cells).any(|c| seen[c] && cover[c] < depth.min(seen_by[c]));
            if !chosen[k] && lifts {
                chosen[k] = true;
                count += 1;
                for (n, &s) in cover.iter_mut().zip(seen) {
                    *n += usize::from(s);
                }
            }
        }
    }
    for ((source, _), c) in ranked.iter().zip(&mut chosen) {
        if count == max {
            break;
        }
        if !*c && source.score >= fill_floor {
            *c = true;
            count += 1;
        }
    }
    ranked
        .iter()
        .zip(&chosen)
        .filter(|(_, c)| **c)
        .map(|((source, _), _)| *source)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use timesift_core::BrownCamera;

    fn nadir(x: f64, y: f64, h: f64) -> Pose {
        // Looking down: camera x = east, y = south, z = down.
        let r = nalgebra::Matrix3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0);
        Pose::from_rt(&r, &Vector3::zeros())
            .map(|p| Pose::from_rotation_and_center(p.rotation, &Vector3::new(x, y, h)))
            .unwrap()
    }

    fn strip(xs: &[f64]) -> EpochInput {
        let camera = Camera::Brown(BrownCamera::new(400, 300, 400.0).unwrap());
        let views: Vec<View> = xs
            .iter()
            .map(|&x| View {
                camera: camera.clone(),
                cam_from_world: nadir(500_000.0 + x, 5_000_000.0, 100.0),
            })
            .collect();
        let mut points = Vec::new();
        for i in 0..40 {
            for j in 0..30 {
                let p = Vector3::new(
                    500_000.0 - 60.0 + 4.0 * i as f64,
                    5_000_000.0 - 45.0 + 3.0 * j as f64,
                    (i % 3) as f64,
                );
                let seen: Vec<usize> = views
                    .iter()
                    .enumerate()
                    .filter(|(_, v)| {
                        let c = v.cam_from_world.transform_point(&p);
                        c.z > 0.0 && (c.x / c.z).abs() < 0.5 && (c.y / c.z).abs() < 0.375
                    })
                    .map(|(k, _)| k)
                    .collect();
                if seen.len() >= 2 {
                    points.push(SparsePoint {
                        position: p,
                        views: seen,
                    });
                }
            }
        }
        EpochInput { views, points }
    }

    #[test]
    fn sources_prefer_overlap_at_a_useful_angle() {
        // View 1 is 2 m from view 0 (1°: too narrow), view 2 is 25 m away (14°), view 3 is 80 m
        // away (little overlap).
        let input = strip(&[0.0, 2.0, 25.0, 80.0]);
        let plan = plan_epoch(&input, &PlanOptions::default()).unwrap();
        let first: Vec<usize> = plan.views[0].sources.iter().map(|s| s.view).collect();
        for (a, v) in plan.views.iter().enumerate() {
            for &b in &v.neighbours {
                assert!(
                    plan.views[b].neighbours.contains(&a),
                    "neighbours are symmetric"
                );
            }
        }
        assert_eq!(first[0], 2, "{:?}", plan.views[0].sources);
        let (near, far) = plan.views[0].depth_range;
        assert!(near < 98.0 * 0.8 && far > 100.0 * 1.2, "{near} {far}");
        // The plan's local frame has small numbers.
        assert!(plan.views[0].cam_from_local.center().norm() < 100.0);
    }

    /// Four views near x = +25 m see the right three quarters of view 0's field and outscore the
    /// one at −70 m, the only view that sees its left border. With room for two sources, the
    /// second is that view, not a fourth look at the middle.
    #[test]
    fn sources_cover_the_borders_of_the_field_before_the_middle_twice() {
        let input = strip(&[0.0, 20.0, 25.0, 30.0, 35.0, -70.0]);
        let all = plan_epoch(&input, &PlanOptions::default()).unwrap();
        let by_score: Vec<usize> = all.views[0].sources.iter().map(|s| s.view).collect();
        let rank = by_score.iter().position(|&v| v == 5);
        assert!(rank.is_some_and(|r| r >= 2), "{by_score:?}");
        let two = PlanOptions {
            max_sources: 2,
            ..PlanOptions::default()
        };
        let plan = plan_epoch(&input, &two).unwrap();
        let sources: Vec<usize> = plan.views[0].sources.iter().map(|s| s.view).collect();
        assert_eq!(sources, vec![by_score[0], 5], "by score: {by_score:?}");
        // Filtering and fusion look wider: the other overlapping views, up to twice as many.
        let links = &plan.views[0].neighbours;
        assert!(
            links.len() >= 4 && sources.iter().all(|s| links.contains(s)),
            "{links:?}"
        );
        // Sources stay in score order, and no more than asked for.
        for v in &plan.views {
            assert!(v.sources.len() <= 2);
            assert!(v.sources.windows(2).all(|w| w[0].score >= w[1].score));
        }
    }

    /// A strip at 53 % overlap: view 2, the next-but-one, sees the last sixth of view 0's field
    /// at about 48°, scoring under 3 % of view 1; it is still a source of view 0 (and view 0 of
    /// view 2), for there it is the only third view.
    #[test]
    fn a_small_overlap_at_a_wide_angle_is_a_source_where_it_is_the_only_third_view() {
        let input = strip(&[0.0, 47.0, 94.0]);
        let plan = plan_epoch(&input, &PlanOptions::default()).unwrap();
        // The score of `source` as a source of `view`, when it is one.
        let score = |view: usize, source: usize| {
            let sources = &plan.views[view].sources;
            sources.iter().find(|s| s.view == source).map(|s| s.score)
        };
        let (Some(near), Some(far)) = (score(0, 1), score(0, 2)) else {
            panic!("view 0's sources: {:?}", plan.views[0].sources);
        };
        assert!(
            far < MIN_RELATIVE_SCORE * near,
            "{:?}",
            plan.views[0].sources
        );
        assert!(
            score(2, 0).is_some(),
            "view 2's sources: {:?}",
            plan.views[2].sources
        );
        assert!(plan.views[0].neighbours.contains(&2));
    }

    /// With tie points shared by two views only (few matches between film scans), the other
    /// overlapping views still become sources through the overlap term.
    #[test]
    fn overlapping_views_are_sources_without_shared_points() {
        let mut input = strip(&[0.0, 25.0, 50.0]);
        for p in &mut input.points {
            p.views.retain(|&v| v != 2);
        }
        // View 2 keeps a few points of its own, for its depth range.
        let own: Vec<SparsePoint> = input
            .points
            .iter()
            .take(5)
            .map(|p| SparsePoint {
                position: p.position,
                views: vec![2],
            })
            .collect();
        input.points.extend(own);
        let plan = plan_epoch(&input, &PlanOptions::default()).unwrap();
        let sources =
            |v: usize| -> Vec<usize> { plan.views[v].sources.iter().map(|s| s.view).collect() };
        assert!(sources(0).contains(&2), "{:?}", sources(0));
        assert!(
            sources(2).contains(&0) && sources(2).contains(&1),
            "{:?}",
            sources(2)
        );
    }

    #[test]
    fn one_view_and_blind_views_are_errors() {
        let input = strip(&[0.0]);
        assert!(matches!(
            plan_epoch(&input, &PlanOptions::default()),
            Err(DenseError::TooFewViews { found: 1, .. })
        ));
        let mut input = strip(&[0.0, 25.0]);
        input.points.clear();
        assert!(matches!(
            plan_epoch(&input, &PlanOptions::default()),
            Err(DenseError::NoDepthRange { view: 0, .. })
        ));
    }
}
