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
use crate::cloud::{PointIndex, fit_plane};
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
    Ok(core_points
        .par_iter()
        .map_init(Scratch::default, |scratch, core| {
            one_core_point(epoch1, epoch2, core, params, &orientation, scratch)
        })
        .collect())
}

/// Per-thread buffers, reused across core points.
#[derive(Default)]
struct Scratch {
    neighbours: Vec<u32>,
    projections: [Vec<f64>; 2],
}

fn one_core_point(
    epoch1: &PointIndex,
    epoch2: &PointIndex,
    core: &[f64; 3],
    params: &M3c2Params,
    orientation: &Vector3<f64>,
    scratch: &mut Scratch,
) -> M3c2Point {
    // Normal: most planar scale of the first cloud.
    let mut best: Option<(f64, Vector3<f64>, f64)> = None;
    for &radius in &params.normal_radii {
        epoch1.within(core, radius, &mut scratch.neighbours);
        if let Some(fit) = fit_plane(epoch1.points(), &scratch.neighbours, core, orientation) {
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
    for (k, index) in [epoch1, epoch2].into_iter().enumerate() {
        let projections = &mut scratch.projections[k];
        cylinder_projections(
            index,
            core,
            &normal,
            params,
            &mut scratch.neighbours,
            projections,
        );
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
                let (median, iqr) = median_and_iqr(projections);
                (median, iqr)
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

/// Projections t = (p − core)·n of the points of `index` in the cylinder (axis distance ≤ r,
/// |t| ≤ max_depth).
fn cylinder_projections(
    index: &PointIndex,
    core: &[f64; 3],
    normal: &Vector3<f64>,
    params: &M3c2Params,
    neighbours: &mut Vec<u32>,
    out: &mut Vec<f64>,
) {
    out.clear();
    let r = params.cylinder_radius;
    let depth = params.max_depth;
    let slabs = (depth / r).ceil().max(1.0) as usize;
    let half = depth / slabs as f64;
    let ball = (r * r + half * half).sqrt();
    let points = index.points();
    for s in 0..slabs {
        let offset = -depth + (2 * s + 1) as f64 * half;
        let centre = [
            core[0] + offset * normal.x,
            core[1] + offset * normal.y,
            core[2] + offset * normal.z,
        ];
        let (lo, hi) = (offset - half, offset + half);
        let last = s + 1 == slabs;
        index.within(&centre, ball, neighbours);
        for &i in neighbours.iter() {
            let p = points[i as usize];
            let d = Vector3::new(p[0] - core[0], p[1] - core[1], p[2] - core[2]);
            let t = d.dot(normal);
            // Half-open slabs so a point on a boundary is counted once; the last one is closed.
            if t < lo || t > hi || (t == hi && !last) {
                continue;
            }
            if (d - t * normal).norm_squared() <= r * r {
                out.push(t);
            }
        }
    }
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
