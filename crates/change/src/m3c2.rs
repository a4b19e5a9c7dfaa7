//! M3C2 (Lague, Brodu & Leroux 2013): signed distances between two point clouds along local surface
//! normals, with a level of detection per core point.
//!
//! For each core point: the normal is the PCA normal of the first cloud's points within the normal
//! radius (with several radii, the most planar scale, (λ1 − λ0)/λ2, wins); the points of each cloud
//! inside a cylinder of radius `cylinder_radius` around the normal axis and within ±`max_depth` of
//! the core point along it are projected on the axis; the distance is the difference of their mean
//! (or median) positions; LoD95 = 1.96 · (sqrt(σ1²/n1 + σ2²/n2) + registration error), σ the spread
//! along the normal (standard deviation with divisor n − 1, or the inter-quartile range in median
//! mode). These are py4dgeo's definitions, so results compare one to one.
//!
//! The cylinder is searched as a stack of short slabs (ball queries of radius sqrt(r² + (L/N)²)), so
//! a long cylinder does not cost a ball of its full length.

use nalgebra::Vector3;
use rayon::prelude::*;
use serde::Serialize;

use crate::ChangeError;
use crate::cloud::{PointIndex, distance_squared, fit_plane};
use crate::error::positive;

/// How the positions inside a cylinder are aggregated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Aggregation {
    /// Mean position; spread = standard deviation along the normal.
    Mean,
    /// Median projection; spread = inter-quartile range.
    Median,
}

/// M3C2 parameters (lengths in metres).
#[derive(Debug, Clone, PartialEq)]
pub struct M3c2Params {
    /// Normal radii (D/2 of Lague et al.); several radii select the most planar scale per point.
    pub normal_radii: Vec<f64>,
    /// Cylinder radius (d/2 of Lague et al.).
    pub cylinder_radius: f64,
    /// Half-length of the cylinder along the normal (points farther along the normal are ignored).
    pub max_depth: f64,
    /// Registration error added to the LoD (m).
    pub registration_error: f64,
    /// Mean or median.
    pub aggregation: Aggregation,
    /// Normals are flipped to point along this direction (default +Z: up).
    pub orientation: [f64; 3],
}

impl Default for M3c2Params {
    fn default() -> Self {
        M3c2Params {
            normal_radii: vec![1.0],
            cylinder_radius: 0.5,
            max_depth: 2.0,
            registration_error: 0.0,
            aggregation: Aggregation::Mean,
            orientation: [0.0, 0.0, 1.0],
        }
    }
}

/// Result at one core point (NaN where undefined).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct M3c2Point {
    /// Distance from the first to the second cloud along the normal, m (NaN when a cylinder is
    /// empty or no normal could be fitted).
    pub distance: f64,
    /// LoD95, m (NaN with fewer than two points in a cylinder in mean mode).
    pub lod95: f64,
    /// Spread along the normal in the first and second cloud.
    pub spread: [f64; 2],
    /// Points in each cylinder.
    pub count: [u32; 2],
    /// The normal used (NaN when none).
    pub normal: [f64; 3],
    /// The normal radius that was selected (NaN when none).
    pub normal_radius: f64,
}

impl M3c2Point {
    /// Whether the change is significant: |distance| > LoD95 (false where either is undefined).
    pub fn significant(&self) -> bool {
        self.distance.abs() > self.lod95
    }

    const UNDEFINED: M3c2Point = M3c2Point {
        distance: f64::NAN,
        lod95: f64::NAN,
        spread: [f64::NAN; 2],
        count: [0; 2],
        normal: [f64::NAN; 3],
        normal_radius: f64::NAN,
    };
}

fn validate(params: &M3c2Params) -> Result<(), ChangeError> {
    if params.normal_radii.is_empty() {
        return Err(ChangeError::InvalidParameter {
            name: "normal_radii",
            reason: "no radius given; at least one was expected".into(),
        });
    }
    for &r in &params.normal_radii {
        positive("normal_radii", r)?;
    }
    positive("cylinder_radius", params.cylinder_radius)?;
    positive("max_depth", params.max_depth)?;
    if !(params.registration_error.is_finite() && params.registration_error >= 0.0) {
        return Err(ChangeError::InvalidParameter {
            name: "registration_error",
            reason: format!(
                "{} given; a finite value ≥ 0 was expected",
                params.registration_error
            ),
        });
    }
    let o = Vector3::from(params.orientation);
    if !(o.norm() > 0.0 && o.iter().all(|c| c.is_finite())) {
        return Err(ChangeError::InvalidParameter {
            name: "orientation",
            reason: "a finite non-zero vector was expected".into(),
        });
    }
    Ok(())
}

/// M3C2 distances from `epoch1` to `epoch2` at `core_points`, computed in parallel.
pub fn m3c2(
    epoch1: &[[f64; 3]],
    epoch2: &[[f64; 3]],
    core_points: &[[f64; 3]],
    params: &M3c2Params,
) -> Result<Vec<M3c2Point>, ChangeError> {
    validate(params)?;
    let (index1, index2) = rayon::join(|| PointIndex::new(epoch1), || PointIndex::new(epoch2));
    let (index1, index2) = (index1?, index2?);
    m3c2_indexed(&index1, &index2, core_points, params)
}

/// M3C2 with prebuilt indices (to reuse them over several runs).
///
/// Two search strategies give the same result (membership is decided on f64 positions by the same
/// tests): when core points are dense (several per tile of one normal radius) and cylinders short
/// (max depth ≤ 4 cylinder radii), each tile gathers its candidates with one k-d tree query per
/// cloud and its core points scan that short, contiguous list; otherwise each core point queries
/// the trees itself (normal ball, then the cylinder as a stack of slabs).
pub fn m3c2_indexed(
    epoch1: &PointIndex,
    epoch2: &PointIndex,
    core_points: &[[f64; 3]],
    params: &M3c2Params,
) -> Result<Vec<M3c2Point>, ChangeError> {
    validate(params)?;
    if let Some(i) = core_points
        .iter()
        .position(|p| !p.iter().all(|c| c.is_finite()))
    {
        return Err(ChangeError::InvalidInput(format!(
            "core point {i} has a non-finite coordinate"
        )));
    }
    let orientation = Vector3::from(params.orientation).normalize();
    let tile = params.normal_radii.iter().copied().fold(0.0, f64::max);
    let tiles = tiles_of(core_points, tile);
    let dense = core_points.len() as f64 >= 2.0 * tiles.len() as f64;
    let short = params.max_depth <= 4.0 * params.cylinder_radius;
    let mut out = vec![M3c2Point::UNDEFINED; core_points.len()];
    if dense && short {
        let results: Vec<(usize, M3c2Point)> = tiles
            .par_iter()
            .map_init(Scratch::default, |scratch, members| {
                gathered_tile(
                    epoch1,
                    epoch2,
                    core_points,
                    members,
                    params,
                    &orientation,
                    scratch,
                )
            })
            .flatten_iter()
            .collect();
        for (i, r) in results {
            out[i] = r;
        }
    } else {
        out.par_iter_mut()
            .zip(core_points.par_iter())
            .for_each_init(Scratch::default, |scratch, (o, core)| {
                let mut search = TreeSearch { epoch1, epoch2 };
                *o = one_core_point(&mut search, core, params, &orientation, scratch);
            });
    }
    Ok(out)
}

/// Core-point indices grouped by cubic tile of side `size`, in a deterministic order.
fn tiles_of(core_points: &[[f64; 3]], size: f64) -> Vec<Vec<u32>> {
    let Some(origin) = core_points.first() else {
        return Vec::new();
    };
    let mut keyed: Vec<([i64; 3], u32)> = core_points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            (
                [0, 1, 2].map(|k| ((p[k] - origin[k]) / size).floor() as i64),
                i as u32,
            )
        })
        .collect();
    keyed.sort_unstable();
    let mut tiles: Vec<Vec<u32>> = Vec::new();
    let mut last = None;
    for (key, i) in keyed {
        if last != Some(key) {
            tiles.push(Vec::new());
            last = Some(key);
        }
        if let Some(t) = tiles.last_mut() {
            t.push(i);
        }
    }
    tiles
}

/// Per-thread buffers, reused across core points.
#[derive(Default)]
struct Scratch {
    neighbourhood: Vec<[f64; 3]>,
    projections: [Vec<f64>; 2],
    candidates: [Vec<[f64; 3]>; 2],
}

/// Where the points around a core point come from.
trait Search {
    /// Positions of the first cloud within `radius` of `centre` (into `out`, cleared first).
    fn ball1(&mut self, centre: &[f64; 3], radius: f64, out: &mut Vec<[f64; 3]>);
    /// Pushes into `out` (cleared first) the projection t on the axis of every point of cloud `k`
    /// (0 or 1) inside the cylinder (see [`in_cylinder`]).
    fn cylinder(
        &mut self,
        k: usize,
        core: &[f64; 3],
        normal: &Vector3<f64>,
        params: &M3c2Params,
        out: &mut Vec<f64>,
    );
}

/// Each core point queries the k-d trees.
struct TreeSearch<'i, 'a> {
    epoch1: &'i PointIndex<'a>,
    epoch2: &'i PointIndex<'a>,
}

impl Search for TreeSearch<'_, '_> {
    fn ball1(&mut self, centre: &[f64; 3], radius: f64, out: &mut Vec<[f64; 3]>) {
        out.clear();
        self.epoch1
            .visit_within(centre, radius, |_, p| out.push(*p));
    }

    fn cylinder(
        &mut self,
        k: usize,
        core: &[f64; 3],
        normal: &Vector3<f64>,
        params: &M3c2Params,
        out: &mut Vec<f64>,
    ) {
        out.clear();
        let index = if k == 0 { self.epoch1 } else { self.epoch2 };
        let (r, depth) = (params.cylinder_radius, params.max_depth);
        let slabs = (depth / r).ceil().max(1.0) as usize;
        let half = depth / slabs as f64;
        // A hair wider than the slab's bounding ball: the caller's slab assignment is by floor().
        let ball = (r * r + half * half).sqrt() * (1.0 + 1e-9);
        for s in 0..slabs {
            let offset = -depth + (2 * s + 1) as f64 * half;
            let centre = [0, 1, 2].map(|a| core[a] + offset * normal[a]);
            index.visit_within(&centre, ball, |_, p| {
                if let Some(t) = in_cylinder(p, core, normal, r * r, depth) {
                    // Each point belongs to one slab, so a point seen by two balls counts once.
                    let slab =
                        (((t + depth) / (2.0 * half)).floor().max(0.0) as usize).min(slabs - 1);
                    if slab == s {
                        out.push(t);
                    }
                }
            });
        }
    }
}

/// Core points of one tile scan candidate lists gathered once for the tile.
struct GatheredSearch<'c> {
    candidates: &'c [Vec<[f64; 3]>; 2],
}

impl Search for GatheredSearch<'_> {
    fn ball1(&mut self, centre: &[f64; 3], radius: f64, out: &mut Vec<[f64; 3]>) {
        out.clear();
        let r2 = radius * radius;
        out.extend(
            self.candidates[0]
                .iter()
                .filter(|p| distance_squared(p, centre) <= r2),
        );
    }

    fn cylinder(
        &mut self,
        k: usize,
        core: &[f64; 3],
        normal: &Vector3<f64>,
        params: &M3c2Params,
        out: &mut Vec<f64>,
    ) {
        out.clear();
        let r2 = params.cylinder_radius * params.cylinder_radius;
        out.extend(
            self.candidates[k]
                .iter()
                .filter_map(|p| in_cylinder(p, core, normal, r2, params.max_depth)),
        );
    }
}

fn gathered_tile(
    epoch1: &PointIndex,
    epoch2: &PointIndex,
    core_points: &[[f64; 3]],
    members: &[u32],
    params: &M3c2Params,
    orientation: &Vector3<f64>,
    scratch: &mut Scratch,
) -> Vec<(usize, M3c2Point)> {
    // Bounding ball of the tile's core points.
    let pts = || members.iter().map(|&i| &core_points[i as usize]);
    let (lo, hi) = pts().fold(
        ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
        |(lo, hi), p| {
            (
                [0, 1, 2].map(|k| lo[k].min(p[k])),
                [0, 1, 2].map(|k| hi[k].max(p[k])),
            )
        },
    );
    let centre = [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k]));
    let spread = pts()
        .map(|p| distance_squared(p, &centre).sqrt())
        .fold(0.0, f64::max);
    let cylinder_reach = params.cylinder_radius.hypot(params.max_depth) * (1.0 + 1e-9);
    let normal_reach = params.normal_radii.iter().copied().fold(0.0, f64::max);
    let mut candidates = std::mem::take(&mut scratch.candidates);
    for (k, (index, reach)) in [
        (epoch1, cylinder_reach.max(normal_reach)),
        (epoch2, cylinder_reach),
    ]
    .into_iter()
    .enumerate()
    {
        candidates[k].clear();
        let list = &mut candidates[k];
        index.visit_within(&centre, reach + spread, |_, p| list.push(*p));
    }
    let mut search = GatheredSearch {
        candidates: &candidates,
    };
    let results = members
        .iter()
        .map(|&i| {
            let core = &core_points[i as usize];
            (
                i as usize,
                one_core_point(&mut search, core, params, orientation, scratch),
            )
        })
        .collect();
    scratch.candidates = candidates;
    results
}

/// The projection t = (p − core)·n when p is in the cylinder: |t| ≤ depth and distance to the axis
/// ≤ r (r2 = r²). The one membership rule of both search strategies.
#[inline]
fn in_cylinder(
    p: &[f64; 3],
    core: &[f64; 3],
    normal: &Vector3<f64>,
    r2: f64,
    depth: f64,
) -> Option<f64> {
    let d = [p[0] - core[0], p[1] - core[1], p[2] - core[2]];
    let t = d[0] * normal.x + d[1] * normal.y + d[2] * normal.z;
    let e = [
        d[0] - t * normal.x,
        d[1] - t * normal.y,
        d[2] - t * normal.z,
    ];
    (t.abs() <= depth && e[0] * e[0] + e[1] * e[1] + e[2] * e[2] <= r2).then_some(t)
}

fn one_core_point(
    search: &mut dyn Search,
    core: &[f64; 3],
    params: &M3c2Params,
    orientation: &Vector3<f64>,
    scratch: &mut Scratch,
) -> M3c2Point {
    // Normal: most planar scale of the first cloud.
    let mut best: Option<(f64, Vector3<f64>, f64)> = None;
    for &radius in &params.normal_radii {
        search.ball1(core, radius, &mut scratch.neighbourhood);
        if let Some(fit) = fit_plane(&scratch.neighbourhood, core, orientation) {
            let planarity = fit.planarity();
            if best.is_none_or(|(p, _, _)| planarity > p) {
                best = Some((planarity, fit.normal, radius));
            }
        }
    }
    let Some((_, normal, normal_radius)) = best else {
        return M3c2Point::UNDEFINED;
    };
    let mut result = M3c2Point {
        normal: [normal.x, normal.y, normal.z],
        normal_radius,
        ..M3c2Point::UNDEFINED
    };
    let mut centre = [f64::NAN; 2];
    for k in 0..2 {
        let projections = &mut scratch.projections[k];
        search.cylinder(k, core, &normal, params, projections);
        let n = projections.len();
        result.count[k] = n as u32;
        if n == 0 {
            return result;
        }
        let (c, spread) = match params.aggregation {
            Aggregation::Mean => {
                let mean = projections.iter().sum::<f64>() / n as f64;
                let var = if n > 1 {
                    projections.iter().map(|t| (t - mean).powi(2)).sum::<f64>() / (n - 1) as f64
                } else {
                    f64::NAN
                };
                (mean, var.sqrt())
            }
            Aggregation::Median => {
                projections.sort_unstable_by(f64::total_cmp);
                median_and_iqr(projections)
            }
        };
        centre[k] = c;
        result.spread[k] = spread;
    }
    result.distance = centre[1] - centre[0];
    let [n1, n2] = result.count.map(|c| c as f64);
    let [s1, s2] = result.spread;
    result.lod95 = 1.96 * ((s1 * s1 / n1 + s2 * s2 / n2).sqrt() + params.registration_error);
    result
}

/// Median and inter-quartile range of sorted values (py4dgeo's order-statistic rules).
fn median_and_iqr(sorted: &[f64]) -> (f64, f64) {
    let n = sorted.len();
    let median = if n % 2 == 0 {
        0.5 * (sorted[n / 2 - 1] + sorted[n / 2])
    } else {
        sorted[n / 2]
    };
    let quartile = |k: usize| {
        if n % 4 == 0 {
            0.5 * (sorted[k - 1] + sorted[k])
        } else {
            sorted[k]
        }
    };
    let (q1, q3) = (quartile(n / 4), quartile(3 * n / 4));
    (median, q3 - q1)
}

/// Core points by voxel subsampling: in each cube of side `spacing`, the point nearest the cube's
/// centre. Deterministic; the result is ordered by voxel.
pub fn subsample_core_points(
    points: &[[f64; 3]],
    spacing: f64,
) -> Result<Vec<[f64; 3]>, ChangeError> {
    positive("spacing", spacing)?;
    let Some(origin) = points.first() else {
        return Ok(Vec::new());
    };
    let mut best: std::collections::BTreeMap<[i64; 3], (f64, usize)> = Default::default();
    for (i, p) in points.iter().enumerate() {
        let mut key = [0i64; 3];
        let mut d2 = 0.0;
        for k in 0..3 {
            let f = (p[k] - origin[k]) / spacing;
            let cell = f.floor();
            key[k] = cell as i64;
            d2 += (f - cell - 0.5).powi(2);
        }
        let entry = best.entry(key).or_insert((f64::INFINITY, i));
        if d2 < entry.0 {
            *entry = (d2, i);
        }
    }
    Ok(best.values().map(|&(_, i)| points[i]).collect())
}
