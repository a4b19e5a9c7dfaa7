//! Surface ties: the later epochs' own tie points held to the reference epoch's surface where
//! the ground did not change.
//!
//! Why: an epoch joins the block through the tie points it shares with the others, and where
//! appearance changed (a beach, a corridor, decades of film) these are few and lie in a band.
//! A band fixes the epoch's position along it but hardly its roll about it: on the rendered
//! beach of `rendered-mar` its 45 ties lie within 60 m of a 180 m-wide corridor and the second
//! epoch's DEM rolls 3.3 mm/m while the block believes it to 0.8. Yet the epoch's own tie
//! points cover the whole corridor, and on stable ground they lie on the surface the reference
//! epoch's tie points describe. Each becomes a height observation (ASP's heights-from-DEM, with
//! the reference epoch's own points as the DEM): thousands of them, across the whole width.
//!
//! Where the ground changed, an epoch's points miss the reference surface. The misses are
//! compared after removing what the block as a whole got wrong (an offset, a tilt and a bend,
//! fitted robustly to all of them); a point that still misses by more than [`KEEP_SIGMAS`] of
//! their scatter is left out, and so is one whose neighbourhood misses on the same side by more
//! than noise allows ([`REGION_Z`]: decimetres of change over an area, below one point's
//! noise); with stable ground given, only points on it are used.
//!
//! The same comparison, made on the final block, is each epoch's decomposition against the
//! reference epoch ([`SurfaceFit`]): offset, two slopes, dome and height scale with their σ.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

use crate::model::{Reconstruction, SparsePoint};
use crate::reference_dem::ReferenceDem;
use crate::stable_ground::StableGround;

/// A height observation of a tie point (by its track): from a reference surface, with its σ.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceHeight {
    /// Index of the point's track in the input's tracks (as the adjustment numbers them: a
    /// strategy that splits tracks may give the block's final points other numbers).
    pub track: usize,
    /// The epoch whose point it is: the one it was compared in (the first, for a point of
    /// several epochs held to a reference DEM, which holds it once).
    pub epoch: usize,
    /// Height of the reference surface at `at`, metres.
    pub height: f64,
    /// Standard deviation of the observation, metres.
    pub sigma: f64,
    /// Where the surface was sampled (x, y): the point's position then.
    pub at: [f64; 2],
    /// The surface's slope there (dz/dx, dz/dy): the observation is the point's height above
    /// the tangent plane, so that the surface holds the block sideways too where it slopes.
    /// Zero for the reference epoch's own surface, whose local planes are too short to say it.
    pub slope: [f64; 2],
}

/// How an epoch's tie points sit on the reference surface: the misses (point height minus the
/// surface's) decomposed by least squares over the points kept, each term with its σ.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceFit {
    /// The epoch (index).
    pub epoch: usize,
    /// Points compared (on the reference surface, stable ground where given).
    pub compared: usize,
    /// Points kept (not missing by more than 2.5 times the scatter about the plane).
    pub kept: usize,
    /// Robust σ of one point's miss about the plane, metres.
    pub sigma: f64,
    /// Offset at the points' centroid, tilt (east and north slopes), metres and m/m.
    pub plane: [f64; 3],
    /// Standard deviations of `plane`.
    pub plane_std: [f64; 3],
    /// Dome fitted beside the plane: the miss per squared metre from the points' centroid
    /// (m/m²), with its σ.
    pub dome: Option<(f64, f64)>,
    /// Height scale fitted beside the plane and the dome: the miss per metre of the reference
    /// surface's height above its own best plane (m/m), with its σ; `None` over ground too
    /// flat to tell it from a tilt.
    pub height_scale: Option<(f64, f64)>,
    /// Centroid of the kept points (x, y, z), where `plane` is referred.
    pub centroid: [f64; 3],
    /// Where the compared points lie (x, y), those kept: ground the epochs agree on.
    pub unchanged: Vec<[f64; 2]>,
    /// Where the compared points that missed the surface lie: ground that changed, or wrong
    /// points.
    pub changed: Vec<[f64; 2]>,
}

impl SurfaceFit {
    /// The tilt's magnitude, mm/m, and its σ (the σ of the slope along the tilt's direction).
    pub fn tilt_mm_per_m(&self) -> (f64, f64) {
        let (gx, gy) = (self.plane[1], self.plane[2]);
        let tilt = gx.hypot(gy);
        let sigma = if tilt > 0.0 {
            ((gx * self.plane_std[1]).powi(2) + (gy * self.plane_std[2]).powi(2)).sqrt() / tilt
        } else {
            self.plane_std[1].max(self.plane_std[2])
        };
        (1e3 * tilt, 1e3 * sigma)
    }
}

/// Fewest observations of a later epoch's point before it is compared: two-view points of a
/// drone block, at its narrow baselines, are too loose in height to say anything of the
/// surface; unless the epoch has too few others ([`TWO_VIEW_BELOW`]) and their rays meet at
/// [`MIN_TWO_VIEW_ANGLE_DEG`] or more.
const MIN_OBSERVATIONS: usize = 3;
/// Smallest angle between the rays of a two-view point that is compared: a film block flown
/// at 60 % forward overlap sees most of its ground in two scans only, at a base-to-height
/// ratio near 0.6 (over 30°), which fixes a height as well as three drone images do
/// (`synth archival`: 49 of 470 points of the oldest epoch seen three times).
const MIN_TWO_VIEW_ANGLE_DEG: f64 = 20.0;
/// An epoch's two-view points are compared only while it has fewer compared points seen
/// [`MIN_OBSERVATIONS`] times than this (twice [`MIN_HELD`]: every other one is held): on a
/// drone block, which has thousands, they only added cross-strip points that tilted
/// `synth corridor`'s stable-area DoD (plane gain 0.048 → 0.077 m).
const TWO_VIEW_BELOW: usize = 2 * MIN_HELD;
/// Reference points fitted by a local plane around each compared point.
const NEIGHBOURS: usize = 8;
/// Fewest of them within [`RADIUS_GROUND_PX`] for the plane.
const MIN_NEIGHBOURS: usize = 5;
/// How far a neighbour may lie, in ground pixels: the reference surface is sampled by its tie
/// points a few metres apart, and the plane through them must not bridge a break of slope.
/// Not widened where the reference epoch's points lie sparser: on `synth archival` a
/// neighbourhood of 1.5 times their spacing (155 m) held every film epoch, but a plane that
/// wide cuts across the valleys and hills it spans, and the stable-area DoD means grew from
/// 0.04–0.20 to 0.21–0.37 m.
const RADIUS_GROUND_PX: f64 = 40.0;
/// σ of the reference surface at a point, ground pixels: a smooth surface (see
/// [`MAX_ROUGHNESS_GROUND_PX`]) sampled by tie points every few metres is known to about half
/// a ground pixel. Not the misses' scatter, which holds the point's own height noise too,
/// already carried by its rays.
const SURFACE_SIGMA_GROUND_PX: f64 = 0.5;
/// Most RMS scatter of the reference points about their local plane, ground pixels: tie points
/// on smooth ground scatter by a fraction of a ground pixel in height; more is ground with
/// no surface between its points (vegetation, buildings, boulders).
const MAX_ROUGHNESS_GROUND_PX: f64 = 3.0;
/// A point missing the surface (after the fitted offset, tilt and dome) by more than this many
/// robust σ is on ground that changed, or a wrong point.
const KEEP_SIGMAS: f64 = 2.5;
/// Fewest compared points of an epoch before its surface ties are used.
const MIN_COMPARED: usize = 30;
/// Smallest RMS relief about the surface's best plane, metres, for a height scale to be fitted.
const MIN_RELIEF: f64 = 1e-3;
/// Smallest eigenvalue of the column-normalised normal matrix, relative to its largest, of a
/// fit that is solved.
const MIN_CONDITION: f64 = 1e-10;
/// Smallest scatter the trimming uses, metres: below it, misses are rounding.
const MIN_SIGMA: f64 = 1e-9;
/// Fewest points an epoch holds to the surface: fewer say too little of its tilt to be worth
/// another adjustment of the block (on `synth shore`, 16 points over three epochs moved the
/// check points by a few millimetres either way, through the adjustment's new outlier bounds).
const MIN_HELD: usize = 100;
/// Fewest points an epoch holds to a reference DEM: the DEM is the datum (no control, or
/// control the user trusts less), so an epoch with few points on stable ground is held by what
/// it has rather than left to its ties with the others. On `synth archival` with a reference
/// DEM and no control, the oldest epoch's 196 kept points (98 held) fell below [`MIN_HELD`]
/// and its DEM tilted 3.5 mm/m against the reference while the others were held to 0.3.
const MIN_HELD_ON_DEM: usize = MIN_COMPARED / 2;
/// Most rounds of the robust fit (trimming, refitting): each round's fit, freed of the points
/// the last one left out, shows more of a changed region (the neighbourhood test needs about
/// twenty on a region raised by twice the points' noise).
const ROBUST_ROUNDS: usize = 30;
/// Compared points (the point among them) by whose misses a point's neighbourhood is judged
/// ([`REGION_Z`]).
const REGION_NEIGHBOURS: usize = 24;
/// How far those neighbours may lie, ground pixels (20 m on `rendered-mar`'s 0.3 m pixels).
const REGION_RADIUS_GROUND_PX: f64 = 70.0;
/// Fewest neighbours within [`REGION_RADIUS_GROUND_PX`] for a neighbourhood to be judged.
const MIN_REGION_NEIGHBOURS: usize = 8;
/// Significance of the median miss of a point's neighbourhood (about the fitted surface, in
/// standard errors of a median of that many misses) beyond which the point is on ground that
/// changed. Why a neighbourhood: ground that changed by a few decimetres over an area (a beach
/// whose sand built up, a sea surface textured differently) misses the surface by less than
/// [`KEEP_SIGMAS`] of the points' own scatter, point by point, yet all its points miss on the
/// same side. On `rendered-mar` the point-by-point bound (0.85 m there) kept 659 points on
/// ground that changed, 405 of them by more than 0.15 m, and holding them rolled the later
/// epoch 0.5 mm/m about the corridor; noise never agrees over two dozen points.
const REGION_Z: f64 = 3.0;
/// Standard error of the median of n normal samples, in σ, times √n.
const MEDIAN_EFFICIENCY: f64 = 1.2533;
/// Most of the points the neighbourhood test may flag: beyond half, the epoch is bent as a
/// whole against the surface (or the ground changed everywhere), and the test says nothing of
/// where; the point-by-point bound decides alone.
const MAX_REGION_SHARE: f64 = 0.5;

/// The reference surface: the reference epoch's tie points (two observations in its images at
/// least), horizontally indexed.
struct ReferenceSurface {
    index: HorizontalIndex,
    heights: Vec<f64>,
}

/// Points indexed by their horizontal position, about the first of them (so that the tree
/// holds small coordinates).
struct HorizontalIndex {
    origin: [f64; 2],
    tree: ImmutableKdTree<f64, 2>,
    /// Each point's position about `origin`.
    xy: Vec<[f64; 2]>,
}

impl HorizontalIndex {
    /// `None` without a point or where the tree cannot be built.
    fn of(points: impl Iterator<Item = [f64; 2]>) -> Option<HorizontalIndex> {
        let mut points = points.peekable();
        let origin = *points.peek()?;
        let xy: Vec<[f64; 2]> = points
            .map(|p| [p[0] - origin[0], p[1] - origin[1]])
            .collect();
        let tree = ImmutableKdTree::new_from_slice(&xy).ok()?;
        Some(HorizontalIndex { origin, tree, xy })
    }

    /// (x, y) about the index's origin.
    fn local(&self, x: f64, y: f64) -> [f64; 2] {
        [x - self.origin[0], y - self.origin[1]]
    }

    /// The `count` points nearest to `q` (about the origin, [`Self::local`]) that lie within
    /// `radius` of it, nearest first.
    fn near(&self, q: &[f64; 2], count: usize, radius: f64) -> impl Iterator<Item = usize> {
        let found = match std::num::NonZeroUsize::new(count) {
            Some(n) => self
                .tree
                .query(q)
                .nearest_n::<SquaredEuclidean<f64>>(n)
                .execute(),
            None => Vec::new(),
        };
        let r2 = radius * radius;
        found
            .into_iter()
            .filter(move |nb| nb.distance <= r2)
            .map(|nb| nb.item as usize)
    }
}

impl ReferenceSurface {
    fn of(rec: &Reconstruction, epoch_of: &[usize], reference: usize) -> Option<Self> {
        let points: Vec<[f64; 3]> = rec
            .points
            .iter()
            .filter(|p| {
                p.observations
                    .iter()
                    .filter(|e| epoch_of.get(e.image.index()) == Some(&reference))
                    .count()
                    >= 2
            })
            .map(|p| [p.position.x, p.position.y, p.position.z])
            .filter(|p| p.iter().all(|v| v.is_finite()))
            .collect();
        Some(ReferenceSurface {
            index: HorizontalIndex::of(points.iter().map(|p| [p[0], p[1]]))?,
            heights: points.iter().map(|p| p[2]).collect(),
        })
    }

    /// The height of a local plane through the nearest reference points at (x, y), when enough
    /// lie within `radius` around it (not all on one side or one line) and off the plane by
    /// `max_roughness` at most (RMS).
    fn height_at(&self, x: f64, y: f64, radius: f64, max_roughness: f64) -> Option<f64> {
        let q = self.index.local(x, y);
        let found: Vec<usize> = self.index.near(&q, NEIGHBOURS, radius).collect();
        // Normal equations of z = a + b dx + c dy about the query: their first row holds the
        // neighbours' count and the sums of their offsets.
        let mut n = Matrix3::<f64>::zeros();
        let mut rhs = Vector3::<f64>::zeros();
        for &i in &found {
            let p = self.index.xy[i];
            let row = Vector3::new(1.0, p[0] - q[0], p[1] - q[1]);
            n += row * row.transpose();
            rhs += row * self.heights[i];
        }
        let c = n[(0, 0)];
        if c < MIN_NEIGHBOURS as f64 {
            return None;
        }
        // The query must lie among its neighbours, not beyond them: the centroid's offset
        // within half the radius.
        let centroid = nalgebra::Vector2::new(n[(0, 1)], n[(0, 2)]) / c;
        if centroid.norm() > 0.5 * radius {
            return None;
        }
        // A plane through points on one line is no plane: the xy spread's smallest eigenvalue.
        let spread = n.fixed_view::<2, 2>(1, 1) / c - centroid * centroid.transpose();
        let chol = n.cholesky()?;
        let smallest = spread.symmetric_eigenvalues().min();
        if !(smallest > (0.1 * radius).powi(2)) {
            return None;
        }
        let plane = chol.solve(&rhs);
        // How far the neighbours lie off their plane (RMS, 3 parameters fitted): vegetation,
        // buildings, blocks of rock are no surface a point between them lies on.
        let mut misfit = 0.0;
        for &i in &found {
            let p = self.index.xy[i];
            let fitted = plane[0] + plane[1] * (p[0] - q[0]) + plane[2] * (p[1] - q[1]);
            misfit += (self.heights[i] - fitted).powi(2);
        }
        let roughness = (misfit / (c - 3.0)).sqrt();
        (plane[0].is_finite() && roughness <= max_roughness).then_some(plane[0])
    }
}

/// One later epoch's point compared with the surface.
#[derive(Clone, Copy)]
struct Compared {
    track: usize,
    position: Vector3<f64>,
    surface: f64,
    /// The surface's slope there, when it says one.
    slope: [f64; 2],
}

/// What an epoch's points are compared with.
enum Surface<'a> {
    /// The reference epoch's tie points: the later epochs' points against them.
    Epoch {
        points: Box<ReferenceSurface>,
        reference: usize,
        radius: f64,
        max_roughness: f64,
    },
    /// A reference DEM: every epoch's points against it.
    Dem(&'a ReferenceDem),
}

impl Surface<'_> {
    /// The surface's height and slope at (x, y), where it is known.
    fn at(&self, x: f64, y: f64) -> Option<(f64, [f64; 2])> {
        match self {
            Surface::Epoch {
                points,
                radius,
                max_roughness,
                ..
            } => points
                .height_at(x, y, *radius, *max_roughness)
                .map(|h| (h, [0.0; 2])),
            Surface::Dem(dem) => dem.sample(x, y),
        }
    }

    /// Whether points seen in several epochs are compared (in each): against a reference
    /// DEM, yes; against the reference epoch's surface, made of them too, no.
    fn takes_ties(&self) -> bool {
        matches!(self, Surface::Dem(_))
    }

    /// Whether an epoch's points are compared: all but the reference epoch's against its own.
    fn compares(&self, epoch: usize) -> bool {
        match self {
            Surface::Epoch { reference, .. } => epoch != *reference,
            Surface::Dem(_) => true,
        }
    }
}

/// The epochs' points compared with the surface, per epoch: those seen in one epoch only, by
/// [`MIN_OBSERVATIONS`] images at least, on `stable` ground where given, where the surface is
/// known.
fn compare(
    rec: &Reconstruction,
    epoch_of: &[usize],
    epochs: usize,
    stable: Option<&StableGround>,
    surface: &Surface<'_>,
) -> Vec<Vec<Compared>> {
    let mut out: Vec<Vec<Compared>> = (0..epochs).map(|_| Vec::new()).collect();
    // Per epoch, the two-view points compared, kept apart until the epoch's count of the
    // others is known.
    let mut two_view: Vec<Vec<Compared>> = (0..epochs).map(|_| Vec::new()).collect();
    for p in &rec.points {
        if !p.position.iter().all(|v| v.is_finite())
            || stable.is_some_and(|s| !s.contains(&p.position))
        {
            continue;
        }
        let Some(seen) = seen_in(p, epoch_of, epochs) else {
            continue;
        };
        let one_epoch = seen.count_ones() == 1;
        if !(one_epoch || surface.takes_ties()) {
            continue;
        }
        let compared_in = |e: &usize| seen.get(*e) && surface.compares(*e);
        if !(0..epochs).any(|e| compared_in(&e)) {
            continue;
        }
        // Their rays' angle only for the points the cheaper tests kept.
        let wide_pair = p.observations.len() < MIN_OBSERVATIONS;
        if wide_pair && !rays_meet_wide(rec, p) {
            continue;
        }
        if let Some((height, slope)) = surface.at(p.position.x, p.position.y) {
            let compared = Compared {
                track: p.track,
                position: p.position,
                surface: height,
                slope,
            };
            for epoch in (0..epochs).filter(compared_in) {
                match wide_pair {
                    true => two_view[epoch].push(compared),
                    false => out[epoch].push(compared),
                }
            }
        }
    }
    for (points, pairs) in out.iter_mut().zip(two_view) {
        if points.len() < TWO_VIEW_BELOW {
            points.extend(pairs);
        }
    }
    out
}

/// The epochs a point is seen in (a bit each), when every observation's image has an epoch
/// below `epochs`.
fn seen_in(p: &SparsePoint, epoch_of: &[usize], epochs: usize) -> Option<EpochBits> {
    let mut seen = EpochBits::default();
    for e in &p.observations {
        let epoch = *epoch_of.get(e.image.index())?;
        if epoch >= epochs || epoch >= EpochBits::CAPACITY {
            return None;
        }
        seen.set(epoch);
    }
    (seen.count_ones() > 0).then_some(seen)
}

/// A set of epochs (the project holds at most 256).
#[derive(Default, Clone, Copy)]
struct EpochBits([u64; 4]);

impl EpochBits {
    const CAPACITY: usize = 256;

    /// Adds epoch `e` (below [`Self::CAPACITY`]).
    fn set(&mut self, e: usize) {
        self.0[e / 64] |= 1 << (e % 64);
    }
    fn get(&self, e: usize) -> bool {
        e < Self::CAPACITY && self.0[e / 64] & (1 << (e % 64)) != 0
    }
    fn count_ones(&self) -> u32 {
        self.0.iter().map(|w| w.count_ones()).sum()
    }
}

/// Whether the two rays of a two-view point meet at [`MIN_TWO_VIEW_ANGLE_DEG`] at least (both
/// images oriented).
fn rays_meet_wide(rec: &Reconstruction, p: &SparsePoint) -> bool {
    let [a, b] = p.observations.as_slice() else {
        return false;
    };
    let centre = |i: usize| rec.poses.get(i).copied().flatten().map(|q| q.center());
    let (Some(ca), Some(cb)) = (centre(a.image.index()), centre(b.image.index())) else {
        return false;
    };
    (ca - p.position).angle(&(cb - p.position)).to_degrees() >= MIN_TWO_VIEW_ANGLE_DEG
}

/// Least squares of each point's miss (its height minus the surface's) on the columns
/// `design` gives it; the solution, its covariance at unit σ, and the residuals. `None` when
/// singular.
fn least_squares(
    points: &[&Compared],
    columns: usize,
    design: &dyn Fn(&Compared, &mut [f64]),
) -> Option<(DVector<f64>, DMatrix<f64>, Vec<f64>)> {
    least_squares_of(points, columns, design, &|p| p.position.z - p.surface)
}

/// [`least_squares`] of any `observed` value of the points.
fn least_squares_of(
    points: &[&Compared],
    columns: usize,
    design: &dyn Fn(&Compared, &mut [f64]),
    observed: &dyn Fn(&Compared) -> f64,
) -> Option<(DVector<f64>, DMatrix<f64>, Vec<f64>)> {
    if points.len() <= columns {
        return None;
    }
    let mut a = DMatrix::<f64>::zeros(points.len(), columns);
    let mut b = DVector::<f64>::zeros(points.len());
    let mut row = vec![0.0; columns];
    for (i, p) in points.iter().enumerate() {
        design(p, &mut row);
        for (j, v) in row.iter().enumerate() {
            a[(i, j)] = *v;
        }
        b[i] = observed(p);
    }
    let normal = a.transpose() * &a;
    // Columns scaled to unit norm before the factorisation: a nearly collinear column must
    // fail it rather than give a huge, meaningless coefficient.
    let scale: Vec<f64> = (0..columns)
        .map(|j| normal[(j, j)].sqrt().max(f64::MIN_POSITIVE))
        .collect();
    let scaled = DMatrix::from_fn(columns, columns, |i, j| {
        normal[(i, j)] / (scale[i] * scale[j])
    });
    let eigen = scaled.clone().symmetric_eigen();
    if !(eigen.eigenvalues.min() > MIN_CONDITION * eigen.eigenvalues.max()) {
        return None;
    }
    let chol = normal.cholesky()?;
    let x = chol.solve(&(a.transpose() * &b));
    let inverse = chol.inverse();
    let residuals = (0..points.len())
        .map(|i| b[i] - (a.row(i) * &x)[(0, 0)])
        .collect();
    x.iter()
        .all(|v| v.is_finite())
        .then_some((x, inverse, residuals))
}

/// Median absolute deviation about the median, scaled to a normal σ.
fn robust_sigma(values: &[f64]) -> f64 {
    let mut v: Vec<f64> = values.to_vec();
    v.sort_by(f64::total_cmp);
    let median = v[v.len() / 2];
    let mut dev: Vec<f64> = v.iter().map(|x| (x - median).abs()).collect();
    dev.sort_by(f64::total_cmp);
    1.4826 * dev[dev.len() / 2]
}

/// The robust fit of one epoch's misses: which points are kept, and the scatter about the
/// fit. What the block as a whole got wrong is a smooth surface: an offset, a tilt, and a bend
/// (a dome: a term in the squared distance from the points' centroid, as radial distortion
/// bends a block; a sag along one strip is not modelled and shows as misses), fitted to the
/// points kept; a point is kept while it misses that surface by [`KEEP_SIGMAS`] of the
/// scatter at most and its neighbourhood does not miss it as a whole ([`REGION_Z`]). The bend
/// is fitted so that an epoch bent against the surface is not taken for ground that changed
/// around its edges, where holding it is what unbends it; where the points cannot fix a
/// quadratic (too few, or along a line), the plane alone. Once surface ties have acted, the
/// held points sit close to the surface and the scatter, over all points, tightens: the bound
/// then also drops points on ground that changed by decimetres, which the first round's bound
/// (2.5 times the misses' scatter before any point was held, 0.3 m on `rendered-mar`) let
/// through. Measured there (`cargo xtask bench coreg`): with the scatter of the never-held
/// points alone in the second round, the later epoch's DEM tilted 1.21 mm/m against its true
/// surface rather than 0.89.
///
/// Against a reference DEM the scatter is that of the never-held points ([`holds`]) alone: the
/// DEM is its own noise, and the held points, pulled onto it closer than their own height noise,
/// would shrink the bound until it trimmed every other point (on a small `synth archival`, the
/// kept points of an epoch fell 622, 346, 274, 257 of about 690 over four rounds).
fn robust_fit(
    points: &[Compared],
    centre: [f64; 2],
    scatter_of_unheld: bool,
    region_radius: f64,
) -> Option<(Vec<bool>, f64)> {
    // Coordinates scaled by the points' extent, so that the quadratic columns are of the
    // plane's size.
    let extent = points
        .iter()
        .map(|p| {
            (p.position.x - centre[0])
                .abs()
                .max((p.position.y - centre[1]).abs())
        })
        .fold(0.0, f64::max)
        .max(f64::MIN_POSITIVE);
    let design = |p: &Compared, row: &mut [f64]| {
        let (dx, dy) = (
            (p.position.x - centre[0]) / extent,
            (p.position.y - centre[1]) / extent,
        );
        row[0] = 1.0;
        row[1] = dx;
        row[2] = dy;
        if row.len() > 3 {
            row[3] = dx * dx + dy * dy;
        }
    };
    let neighbourhoods = Neighbourhoods::of(points, region_radius);
    // The points whose misses say what one point's noise is.
    let for_sigma: Vec<bool> = points
        .iter()
        .map(|p| !(scatter_of_unheld && holds(p.track)))
        .collect();
    let mut keep = vec![true; points.len()];
    let mut sigma = f64::INFINITY;
    for _ in 0..ROBUST_ROUNDS {
        let kept: Vec<&Compared> = points
            .iter()
            .zip(&keep)
            .filter(|(_, k)| **k)
            .map(|(p, _)| p)
            .collect();
        let (x, columns) = match least_squares(&kept, 4, &design) {
            Some((x, _, _)) => (x, 4),
            None => (least_squares(&kept, 3, &design)?.0, 3),
        };
        let mut row = [0.0; 4];
        let misses: Vec<f64> = points
            .iter()
            .map(|p| {
                design(p, &mut row[..columns]);
                let fitted: f64 = row[..columns]
                    .iter()
                    .zip(x.iter())
                    .map(|(a, b)| a * b)
                    .sum();
                p.position.z - p.surface - fitted
            })
            .collect();
        let kept_misses: Vec<f64> = misses
            .iter()
            .zip(points)
            .zip(&keep)
            .filter(|((_, p), k)| **k && !(scatter_of_unheld && holds(p.track)))
            .map(|((m, _), _)| *m)
            .collect();
        if kept_misses.is_empty() {
            return None;
        }
        sigma = robust_sigma(&kept_misses);
        if !sigma.is_finite() {
            return None;
        }
        // Noise-free misses (σ 0) keep what the plane fits to rounding.
        let bound = KEEP_SIGMAS * sigma.max(MIN_SIGMA);
        let mut next: Vec<bool> = misses.iter().map(|m| m.abs() <= bound).collect();
        neighbourhoods.leave_out_changed(&misses, &for_sigma, &mut next);
        if next == keep {
            break;
        }
        keep = next;
        if keep.iter().filter(|k| **k).count() < MIN_COMPARED {
            return None;
        }
    }
    Some((keep, sigma))
}

/// Each compared point's neighbourhood: the nearest [`REGION_NEIGHBOURS`] compared points
/// within a radius, itself among them; empty where fewer than [`MIN_REGION_NEIGHBOURS`] lie
/// there.
struct Neighbourhoods {
    /// Indices into the points, [`REGION_NEIGHBOURS`] at most per point.
    of_point: Vec<Vec<u32>>,
}

impl Neighbourhoods {
    fn of(points: &[Compared], radius: f64) -> Neighbourhoods {
        let empty = || Neighbourhoods {
            of_point: vec![Vec::new(); points.len()],
        };
        let Some(index) = HorizontalIndex::of(points.iter().map(|p| [p.position.x, p.position.y]))
        else {
            return empty();
        };
        let of_point = index
            .xy
            .iter()
            .map(|q| {
                let near: Vec<u32> = index
                    .near(q, REGION_NEIGHBOURS, radius)
                    .map(|i| i as u32)
                    .collect();
                if near.len() >= MIN_REGION_NEIGHBOURS {
                    near
                } else {
                    Vec::new()
                }
            })
            .collect();
        Neighbourhoods { of_point }
    }

    /// Clears `keep` of the points whose neighbourhood's median miss lies beyond [`REGION_Z`]
    /// standard errors, unless that would clear more than [`MAX_REGION_SHARE`] of the points
    /// `keep` holds. One point's σ is the scatter of the misses about their neighbourhoods'
    /// medians: the points' own noise, which ground that changed as a whole does not widen (the
    /// scatter about the plane holds the change too, and once points are trimmed it shrinks
    /// with every round), over the points `for_sigma` names (against a reference DEM, those
    /// never held: the held ones sit closer to it than their noise).
    fn leave_out_changed(&self, misses: &[f64], for_sigma: &[bool], keep: &mut [bool]) {
        let mut scratch = Vec::with_capacity(REGION_NEIGHBOURS);
        let medians: Vec<Option<f64>> = self
            .of_point
            .iter()
            .map(|near| {
                if near.is_empty() {
                    return None;
                }
                scratch.clear();
                scratch.extend(near.iter().map(|&j| misses[j as usize]));
                let middle = scratch.len() / 2;
                let (_, median, _) = scratch.select_nth_unstable_by(middle, f64::total_cmp);
                Some(*median)
            })
            .collect();
        let about_neighbours: Vec<f64> = misses
            .iter()
            .zip(&medians)
            .zip(for_sigma)
            .filter(|(_, counts)| **counts)
            .filter_map(|((m, median), _)| median.map(|median| m - median))
            .collect();
        if about_neighbours.is_empty() {
            return;
        }
        let sigma = robust_sigma(&about_neighbours).max(MIN_SIGMA);
        let changed: Vec<bool> = medians
            .iter()
            .zip(&self.of_point)
            .map(|(median, near)| {
                median.is_some_and(|median| {
                    let standard_error = MEDIAN_EFFICIENCY * sigma / (near.len() as f64).sqrt();
                    median.abs() > REGION_Z * standard_error
                })
            })
            .collect();
        let kept = keep.iter().filter(|k| **k).count();
        let flagged = keep
            .iter()
            .zip(&changed)
            .filter(|(k, c)| **k && **c)
            .count();
        tracing::debug!(
            kept,
            flagged,
            sigma,
            "neighbourhoods that missed the surface"
        );
        if (flagged as f64) > MAX_REGION_SHARE * kept as f64 {
            return;
        }
        for (k, c) in keep.iter_mut().zip(changed) {
            *k &= !c;
        }
    }
}

/// The decomposition of the kept points' misses (plane; dome and height scale beside it) with
/// its σ. The height scale's regressor is the reference surface's height above its own best
/// plane: over planar ground a height scale cannot be told from a tilt, and is not fitted.
fn decompose(epoch: usize, points: &[Compared], keep: &[bool]) -> Option<SurfaceFit> {
    let kept: Vec<&Compared> = points
        .iter()
        .zip(keep)
        .filter(|(_, k)| **k)
        .map(|(p, _)| p)
        .collect();
    let n = kept.len() as f64;
    let centroid = kept.iter().fold([0.0; 3], |c, p| {
        [
            c[0] + p.position.x / n,
            c[1] + p.position.y / n,
            c[2] + p.position.z / n,
        ]
    });
    let plane_design = |p: &Compared, row: &mut [f64]| {
        row[0] = 1.0;
        row[1] = p.position.x - centroid[0];
        row[2] = p.position.y - centroid[1];
    };
    let (plane, plane_cov, residuals) = least_squares(&kept, 3, &plane_design)?;
    let s = robust_sigma(&residuals);
    let std = |s: f64, cov: &DMatrix<f64>, i: usize| s * cov[(i, i)].max(0.0).sqrt();
    // The surface's own best plane, to take out of its heights.
    let relief = least_squares_of(&kept, 3, &plane_design, &|p| p.surface).map(|(x, _, _)| x)?;
    let above = |p: &Compared| {
        p.surface
            - (relief[0]
                + relief[1] * (p.position.x - centroid[0])
                + relief[2] * (p.position.y - centroid[1]))
    };
    let relief_spread = (kept.iter().map(|p| above(p).powi(2)).sum::<f64>() / n).sqrt();
    let shape_design = |p: &Compared, row: &mut [f64]| {
        let (dx, dy) = (p.position.x - centroid[0], p.position.y - centroid[1]);
        row[0] = 1.0;
        row[1] = dx;
        row[2] = dy;
        row[3] = dx * dx + dy * dy;
        if row.len() > 4 {
            row[4] = above(p);
        }
    };
    let with_scale = relief_spread > MIN_RELIEF;
    let columns = if with_scale { 5 } else { 4 };
    let shape = least_squares(&kept, columns, &shape_design).map(|(x, cov, residuals)| {
        let s = robust_sigma(&residuals);
        let term = |i: usize| (i < columns).then(|| (x[i], std(s, &cov, i)));
        (term(3), term(4))
    });
    let (dome, height_scale) = shape.unwrap_or((None, None));
    Some(SurfaceFit {
        epoch,
        compared: points.len(),
        kept: kept.len(),
        sigma: s,
        plane: [plane[0], plane[1], plane[2]],
        plane_std: [
            std(s, &plane_cov, 0),
            std(s, &plane_cov, 1),
            std(s, &plane_cov, 2),
        ],
        dome,
        height_scale,
        centroid,
        unchanged: points
            .iter()
            .zip(keep)
            .filter(|(_, k)| **k)
            .map(|(p, _)| [p.position.x, p.position.y])
            .collect(),
        changed: points
            .iter()
            .zip(keep)
            .filter(|(_, k)| !**k)
            .map(|(p, _)| [p.position.x, p.position.y])
            .collect(),
    })
}

/// One later epoch against the reference epoch's surface: its fit, and the height
/// observations its points would get.
pub(crate) struct EpochSurface {
    pub fit: SurfaceFit,
    pub held: Vec<SurfaceHeight>,
}

/// How a block's later epochs' points are compared with the reference epoch's surface: the
/// epochs, and where the ground is known stable.
pub(crate) struct SurfaceComparison<'a> {
    pub epoch_of: &'a [usize],
    pub reference: usize,
    pub epochs: usize,
    pub stable: Option<&'a StableGround>,
    /// The block's median ground pixel, metres: the scale of the neighbourhoods and bounds.
    pub ground_px: f64,
    /// A reference DEM: every epoch is compared with it instead of the later epochs with the
    /// reference epoch's surface.
    pub dem: Option<&'a ReferenceDem>,
}

impl SurfaceComparison<'_> {
    /// The epochs' points compared with the surface.
    fn compared(&self, rec: &Reconstruction) -> Vec<Vec<Compared>> {
        let surface = match self.dem {
            Some(dem) => Surface::Dem(dem),
            None => {
                let Some(points) = ReferenceSurface::of(rec, self.epoch_of, self.reference) else {
                    return (0..self.epochs).map(|_| Vec::new()).collect();
                };
                Surface::Epoch {
                    points: Box::new(points),
                    reference: self.reference,
                    radius: RADIUS_GROUND_PX * self.ground_px,
                    max_roughness: MAX_ROUGHNESS_GROUND_PX * self.ground_px,
                }
            }
        };
        compare(rec, self.epoch_of, self.epochs, self.stable, &surface)
    }

    /// How far a point's neighbourhood reaches, metres ([`REGION_RADIUS_GROUND_PX`]).
    fn region_radius(&self) -> f64 {
        REGION_RADIUS_GROUND_PX * self.ground_px
    }

    /// Per later epoch compared, its fit against the reference epoch's surface (before the
    /// observations act) and the height observations its points would get (every other one,
    /// [`holds`]; none below [`MIN_HELD`], or [`MIN_HELD_ON_DEM`] against a reference DEM).
    pub fn heights(&self, rec: &Reconstruction) -> Vec<EpochSurface> {
        let mut epochs = Vec::new();
        for (epoch, points) in self.compared(rec).iter().enumerate() {
            let Some((keep, _, fit)) =
                fit_epoch(epoch, points, self.dem.is_some(), self.region_radius())
            else {
                continue;
            };
            // The observation's σ is the surface's, not the misses' scatter: that holds the
            // point's own height noise too, which its rays already carry in the adjustment.
            let sigma = self
                .dem
                .map_or(SURFACE_SIGMA_GROUND_PX * self.ground_px, |d| d.sigma());
            let mut held: Vec<SurfaceHeight> = points
                .iter()
                .zip(&keep)
                .filter(|(p, k)| **k && holds(p.track))
                .map(|(p, _)| SurfaceHeight {
                    track: p.track,
                    epoch,
                    height: p.surface,
                    sigma,
                    at: [p.position.x, p.position.y],
                    slope: p.slope,
                })
                .collect();
            let fewest = match self.dem {
                Some(_) => MIN_HELD_ON_DEM,
                None => MIN_HELD,
            };
            if held.len() < fewest {
                held.clear();
            }
            epochs.push(EpochSurface { fit, held });
        }
        epochs
    }

    /// Each later epoch's decomposition against the reference epoch's surface, on a block as
    /// it is (its final state, for the report), from the points [`Self::heights`] never holds.
    pub fn fits(&self, rec: &Reconstruction) -> Vec<SurfaceFit> {
        self.compared(rec)
            .into_iter()
            .enumerate()
            .filter_map(|(epoch, mut points)| {
                points.retain(|p| !holds(p.track));
                fit_epoch(epoch, &points, self.dem.is_some(), self.region_radius())
                    .map(|(_, _, fit)| fit)
            })
            .collect()
    }
}

/// Whether a point (by track) may be held to the surface: every other one. The others are
/// never held, so that [`SurfaceComparison::fits`] measures how the epoch as a whole sits on
/// the surface, not how closely the adjustment pulled the held points onto it.
fn holds(track: usize) -> bool {
    track % 2 == 0
}

/// The robust plane of one epoch's compared points, the points kept and their scatter, and
/// the decomposition; `None` with too few points or a fit that fails.
fn fit_epoch(
    epoch: usize,
    points: &[Compared],
    scatter_of_unheld: bool,
    region_radius: f64,
) -> Option<(Vec<bool>, f64, SurfaceFit)> {
    if points.len() < MIN_COMPARED {
        return None;
    }
    let n = points.len() as f64;
    let centre = points.iter().fold([0.0; 2], |c, p| {
        [c[0] + p.position.x / n, c[1] + p.position.y / n]
    });
    let (keep, sigma) = robust_fit(points, centre, scatter_of_unheld, region_radius)?;
    let fit = decompose(epoch, points, &keep)?;
    Some((keep, sigma, fit))
}

#[cfg(test)]
mod tests {
    use timesift_core::{FeatureIndex, ImageId, Pose, SeededRng, TrackElement};

    use super::*;
    use crate::model::SparsePoint;

    /// Images 0–2 in epoch 0 (the reference), 3–5 in epoch 1.
    const EPOCH_OF: [usize; 6] = [0, 0, 0, 1, 1, 1];

    /// Whether a point of [`scene`] is the later epoch's (images 3–5).
    fn is_later(p: &SparsePoint) -> bool {
        p.observations[0].image.index() >= 3
    }

    /// The fit's slopes are [`planted`]'s within 4 σ.
    fn assert_planted_slopes(f: &SurfaceFit) {
        for k in 1..3 {
            assert!(
                (f.plane[k] * 1e3 - [0.0, 3.0, -1.0][k]).abs() < 4.0 * f.plane_std[k] * 1e3,
                "{:?} ± {:?}",
                f.plane,
                f.plane_std
            );
        }
    }

    /// How many of the held points lie where `at(x, y)` holds.
    fn held_where(
        heights: &[SurfaceHeight],
        rec: &Reconstruction,
        at: impl Fn(f64, f64) -> bool,
    ) -> usize {
        heights
            .iter()
            .filter(|h| {
                let p = &rec.points[h.track].position;
                at(p.x, p.y)
            })
            .count()
    }

    /// Every epoch's height observations, and the fits.
    fn split(epochs: Vec<EpochSurface>) -> (Vec<SurfaceHeight>, Vec<SurfaceFit>) {
        epochs
            .into_iter()
            .fold((Vec::new(), Vec::new()), |(mut h, mut f), e| {
                h.extend(e.held);
                f.push(e.fit);
                (h, f)
            })
    }

    /// The comparison of the two epochs, at a ground pixel of 0.2 m.
    fn compare_with(stable: Option<&StableGround>) -> SurfaceComparison<'_> {
        SurfaceComparison {
            epoch_of: &EPOCH_OF,
            reference: 0,
            epochs: 2,
            stable,
            ground_px: 0.2,
            dem: None,
        }
    }

    /// The true ground: a slope of 5 % east and 2 % north.
    fn ground(x: f64, y: f64) -> f64 {
        10.0 + 0.05 * x + 0.02 * y
    }

    fn point(track: usize, position: Vector3<f64>, images: &[usize]) -> SparsePoint {
        SparsePoint {
            position,
            track,
            observations: images
                .iter()
                .map(|&i| TrackElement {
                    image: ImageId::from(i),
                    feature: FeatureIndex::from(track),
                })
                .collect(),
        }
    }

    /// Reference points on a 3 m grid over 180 × 120 m, and later points between them with a
    /// planted miss (offset + tilt), `noise` σ, and, inside `changed`, 1 m of change.
    fn scene(
        noise: f64,
        miss: impl Fn(f64, f64) -> f64,
        changed: impl Fn(f64, f64) -> bool,
    ) -> Reconstruction {
        scene_changed_by(noise, miss, |x, y| if changed(x, y) { 1.0 } else { 0.0 })
    }

    /// [`scene`] with the later points raised by `change` (metres) where the ground changed.
    fn scene_changed_by(
        noise: f64,
        miss: impl Fn(f64, f64) -> f64,
        change: impl Fn(f64, f64) -> f64,
    ) -> Reconstruction {
        let mut rng = SeededRng::new(7);
        let mut points = Vec::new();
        for i in 0..60 {
            for j in 0..40 {
                let (x, y) = (3.0 * i as f64, 3.0 * j as f64);
                let reference = Vector3::new(x, y, ground(x, y));
                let (x, y) = (x + 1.3, y + 1.7);
                let change = change(x, y);
                let z = ground(x, y) + miss(x, y) + change + noise * rng.normal();
                let later = Vector3::new(x, y, z);
                // Tracks in varying order, so that later points have both parities.
                let (first, second) = match j % 2 {
                    0 => ((reference, [0, 1, 2]), (later, [3, 4, 5])),
                    _ => ((later, [3, 4, 5]), (reference, [0, 1, 2])),
                };
                for (position, images) in [first, second] {
                    let track = points.len();
                    points.push(point(track, position, &images));
                }
            }
        }
        Reconstruction {
            cameras: Vec::new(),
            poses: vec![None; 6],
            points,
        }
    }

    fn planted(x: f64, y: f64) -> f64 {
        -0.3 + 0.003 * (x - 90.0) - 0.001 * (y - 60.0)
    }

    #[test]
    fn a_planted_offset_and_tilt_is_recovered_exactly_without_noise() {
        let rec = scene(0.0, planted, |_, _| false);
        let (heights, fits) = split(compare_with(None).heights(&rec));
        assert_eq!(fits.len(), 1);
        let f = &fits[0];
        assert_eq!(f.epoch, 1);
        // The later points' misses at their centroid, and the slopes.
        let expected = planted(f.centroid[0], f.centroid[1]);
        assert!((f.plane[0] - expected).abs() < 1e-9, "{:?}", f.plane);
        assert!((f.plane[1] - 0.003).abs() < 1e-9, "{:?}", f.plane);
        assert!((f.plane[2] + 0.001).abs() < 1e-9, "{:?}", f.plane);
        // No dome; over a planar surface no height scale is fitted.
        assert!(f.dome.is_some_and(|(d, _)| d.abs() < 1e-12), "{:?}", f.dome);
        assert_eq!(f.height_scale, None);
        // Every height observation is the true ground under its point (the reference
        // surface is a plane, which the local planes reproduce exactly).
        // Every other point is held; the others are left to check the fit.
        assert!(heights.len() > 1000, "{}", heights.len());
        assert!(heights.iter().all(|h| holds(h.track)));
        let checked = compare_with(None).fits(&rec);
        assert!(
            (checked[0].plane[1] - 0.003).abs() < 1e-9,
            "{:?}",
            checked[0].plane
        );
        assert!(checked[0].kept + heights.len() <= f.kept + 1);
        for h in &heights {
            let p = &rec.points[h.track];
            assert!((h.height - ground(p.position.x, p.position.y)).abs() < 1e-9);
        }
    }

    /// The true ground (a plane: [`ground`]) as a 1 m reference DEM over the scene, σ 0.3 m.
    fn ground_dem() -> ReferenceDem {
        let (width, height) = (200, 140);
        let heights = (0..height)
            .flat_map(|r| (0..width).map(move |c| (r, c)))
            .map(|(r, c)| ground(-10.0 + 0.5 + c as f64, 130.0 - 0.5 - r as f64) as f32)
            .collect();
        ReferenceDem::new([-10.0, 130.0], 1.0, [width, height], heights, 0.3).expect("dem")
    }

    #[test]
    fn against_a_reference_dem_every_epoch_is_compared_and_held_on_its_tangent_plane() {
        let rec = scene(0.0, planted, |_, _| false);
        let dem = ground_dem();
        let comparison = SurfaceComparison {
            dem: Some(&dem),
            ..compare_with(None)
        };
        let (heights, fits) = split(comparison.heights(&rec));
        // The reference epoch too: it sits on the DEM; the later one misses it by the plant.
        assert_eq!(fits.iter().map(|f| f.epoch).collect::<Vec<_>>(), [0, 1]);
        assert!(
            fits[0].plane.iter().all(|v| v.abs() < 1e-5),
            "{:?}",
            fits[0].plane
        );
        let f = &fits[1];
        let expected = planted(f.centroid[0], f.centroid[1]);
        assert!((f.plane[0] - expected).abs() < 1e-5, "{:?}", f.plane);
        assert!((f.plane[1] - 0.003).abs() < 1e-6 && (f.plane[2] + 0.001).abs() < 1e-6);
        // Every held height is the DEM's at its point, with the DEM's σ and slope.
        assert!(heights.len() > 2000, "{}", heights.len());
        for h in &heights {
            let p = &rec.points[h.track].position;
            assert_eq!(h.at, [p.x, p.y]);
            assert!((h.height - ground(p.x, p.y)).abs() < 1e-4);
            assert!((h.slope[0] - 0.05).abs() < 1e-4 && (h.slope[1] - 0.02).abs() < 1e-4);
            assert_eq!(h.sigma, 0.3);
        }
    }

    #[test]
    fn an_epoch_with_few_points_is_held_to_a_reference_dem_but_not_to_the_reference_epoch() {
        // The later epoch keeps 70 points in one corner, 10 columns of 7 (those of even track,
        // 3 of the 7 rows, would be held): too few to be worth holding to the reference
        // epoch's surface, enough to hold it to a DEM.
        let mut rec = scene(0.0, planted, |_, _| false);
        rec.points
            .retain(|p| !is_later(p) || (p.position.x < 30.0 && p.position.y < 20.0));
        assert_eq!(rec.points.iter().filter(|p| is_later(p)).count(), 70);
        let later_held =
            |heights: &[SurfaceHeight]| heights.iter().filter(|h| h.epoch == 1).count();
        let (on_epoch, _) = split(compare_with(None).heights(&rec));
        assert_eq!(later_held(&on_epoch), 0);
        let dem = ground_dem();
        let comparison = SurfaceComparison {
            dem: Some(&dem),
            ..compare_with(None)
        };
        let (on_dem, fits) = split(comparison.heights(&rec));
        assert_eq!(later_held(&on_dem), 30);
        let f = fits
            .iter()
            .find(|f| f.epoch == 1)
            .expect("the later epoch's fit");
        assert!((f.plane[1] - 0.003).abs() < 1e-6, "{:?}", f.plane);
    }

    #[test]
    fn changed_ground_is_left_out_and_the_tilt_found_within_its_sigma_under_noise() {
        let changed = |x: f64, y: f64| x > 120.0 && y < 50.0;
        let rec = scene(0.1, planted, changed);
        let (heights, fits) = split(compare_with(None).heights(&rec));
        let f = &fits[0];
        let (tilt, sigma) = f.tilt_mm_per_m();
        let truth = 0.003f64.hypot(0.001) * 1e3;
        assert!(
            sigma > 0.0 && (tilt - truth).abs() < 4.0 * sigma,
            "{tilt} ± {sigma}"
        );
        assert!((f.sigma - 0.1).abs() < 0.02, "σ {}", f.sigma);
        assert_planted_slopes(f);
        // No point on the changed ground is held to the surface.
        let on_change = held_where(&heights, &rec, changed);
        assert_eq!(on_change, 0);
        // The final fit (on the points never held) says where the ground changed.
        let checked = &compare_with(None).fits(&rec)[0];
        assert!(checked.changed.len() > 100, "{}", checked.changed.len());
        // Stable points taken for changed: beyond a neighbourhood's reach of the change (the
        // 24 nearest points of a 3 m grid lie within 9 m), only the 2.5 σ test's false alarms
        // on normal noise (1.2 %).
        let off_change = |p: &[f64; 2]| (120.0 - p[0]).max(p[1] - 50.0);
        let misplaced = checked
            .changed
            .iter()
            .filter(|p| off_change(p) > 9.0)
            .count();
        assert!(
            misplaced * 100 <= 3 * checked.unchanged.len(),
            "{misplaced} of {}",
            checked.unchanged.len()
        );

        assert!(checked.unchanged.iter().all(|p| !changed(p[0], p[1])));
    }

    #[test]
    fn ground_that_changed_by_less_than_the_noise_is_found_by_its_neighbourhood() {
        // A seventh of the later points (5/36 of the scene) raised 0.5 m, within the
        // point-by-point bound (2.5 σ of noise 0.3 m): the same side of the surface over the
        // whole region.
        let changed = |x: f64, y: f64| x > 120.0 && y < 50.0;
        let rec = scene_changed_by(0.3, planted, |x, y| if changed(x, y) { 0.5 } else { 0.0 });
        let (heights, fits) = split(compare_with(None).heights(&rec));
        let on_change = held_where(&heights, &rec, changed);
        // Of the region's points that would be held (every other one), a third at most still
        // is: those near its edges, whose neighbourhoods straddle it, and the few whose
        // neighbourhoods' noise hides the change.
        let region = rec
            .points
            .iter()
            .filter(|p| is_later(p) && holds(p.track))
            .filter(|p| changed(p.position.x, p.position.y))
            .count();
        assert!(
            on_change * 3 < region,
            "{on_change} of the changed region's {region} points held"
        );
        assert!(heights.len() > 300, "{}", heights.len());
        // The tilt is the planted one: the raised region would tilt a plane through every
        // point by 1.3 mm/m.
        assert_planted_slopes(&fits[0]);
        // Without the change, the neighbourhoods leave out no more than their test's false
        // alarms.
        let rec = scene_changed_by(0.3, planted, |_, _| 0.0);
        let (heights, fits) = split(compare_with(None).heights(&rec));
        assert!(
            fits[0].kept * 100 >= 95 * fits[0].compared,
            "{} of {}",
            fits[0].kept,
            fits[0].compared
        );
        assert!(heights.len() > 1000, "{}", heights.len());
    }

    #[test]
    fn an_epoch_bent_as_a_whole_is_not_taken_for_changed_ground() {
        // A bowl of 0.3 m at the scene's corners (radial distortion left in a later epoch),
        // under noise of 0.1 m: every neighbourhood off the plane, so the test says nothing.
        let bowl = |x: f64, y: f64| 0.3 * ((x - 90.0).powi(2) + (y - 60.0).powi(2)) / 10_800.0;
        let rec = scene_changed_by(0.1, bowl, |_, _| 0.0);
        let (_, fits) = split(compare_with(None).heights(&rec));
        let f = &fits[0];
        assert!(
            f.kept * 100 >= 90 * f.compared,
            "{} of {} kept",
            f.kept,
            f.compared
        );
        let (dome, sigma) = f.dome.expect("dome");
        assert!(
            (dome - 0.3 / 10_800.0).abs() < 4.0 * sigma,
            "dome {dome} ± {sigma}"
        );
    }

    #[test]
    fn stable_ground_given_limits_the_comparison_to_it() {
        let rec = scene(0.0, planted, |_, _| false);
        let stable =
            StableGround::rasterise([0.0, 0.0], 1.0, 200, 130, |x, _| x < 60.0).expect("grid");
        let (heights, fits) = split(compare_with(Some(&stable)).heights(&rec));
        assert!(!heights.is_empty());
        assert!(
            heights
                .iter()
                .all(|h| rec.points[h.track].position.x < 60.0)
        );
        assert!(fits[0].compared < 1000, "{}", fits[0].compared);
    }

    #[test]
    fn too_few_points_or_a_reference_on_one_line_give_no_heights() {
        // 20 later points: fewer than the fit needs.
        let mut rec = scene(0.0, planted, |_, _| false);
        let mut later = 0;
        rec.points.retain(|p| {
            let keep = p.observations[0].image.index() < 3 || later < 20;
            later += usize::from(p.observations[0].image.index() >= 3);
            keep
        });
        let (heights, fits) = split(compare_with(None).heights(&rec));
        assert!(heights.is_empty() && fits.is_empty());
        // Reference points along one line: no local plane anywhere.
        let mut rec = scene(0.0, planted, |_, _| false);
        rec.points
            .retain(|p| p.observations[0].image.index() >= 3 || p.position.y == 0.0);
        let (heights, fits) = split(compare_with(None).heights(&rec));
        assert!(heights.is_empty() && fits.is_empty());
        // Reference points scattered by 3 m RMS about the ground (15 ground pixels of 0.2 m):
        // vegetation, not a surface.
        let mut rec = scene(0.0, planted, |_, _| false);
        let mut rng = SeededRng::new(11);
        for p in rec
            .points
            .iter_mut()
            .filter(|p| p.observations[0].image.index() < 3)
        {
            p.position.z += 3.0 * rng.uniform_range(-1.0, 1.0) * 3f64.sqrt();
        }
        let (heights, fits) = split(compare_with(None).heights(&rec));
        assert!(heights.is_empty() && fits.is_empty(), "{}", heights.len());
        // Non-finite positions are skipped, never propagated.
        let mut rec = scene(0.0, planted, |_, _| false);
        rec.points[1].position.z = f64::NAN;
        let (heights, fits) = split(compare_with(None).heights(&rec));
        assert!(heights.iter().all(|h| h.height.is_finite() && h.track != 1));
        assert!(fits[0].plane.iter().all(|v| v.is_finite()));
    }

    /// [`scene`] without noise or change, its later points seen by the `later` images; no
    /// image oriented.
    fn scene_seen_by(later: &[usize]) -> Reconstruction {
        let mut rec = scene(0.0, planted, |_, _| false);
        for p in &mut rec.points {
            if p.observations[0].image.index() >= 3 {
                *p = point(p.track, p.position, later);
            }
        }
        rec
    }

    #[test]
    fn two_view_points_are_compared_only_where_their_rays_meet_wide() {
        // Images 3 and 4 at 100 m above the block's centre, `base` apart.
        let with_base = |base: f64| {
            let mut rec = scene_seen_by(&[3, 4]);
            for (image, dx) in [(3, -0.5 * base), (4, 0.5 * base)] {
                let centre = Vector3::new(90.0 + dx, 60.0, 110.0);
                rec.poses[image] = Some(Pose::new(nalgebra::UnitQuaternion::identity(), -centre));
            }
            rec
        };
        // A base of 60 m at 100 m: rays about 33° apart, as a film block's at 60 % overlap.
        let (heights, fits) = split(compare_with(None).heights(&with_base(60.0)));
        assert!(
            fits[0].compared > 2000 && heights.len() > 1000,
            "{}",
            fits[0].compared
        );
        assert!(
            (fits[0].plane[1] - 0.003).abs() < 1e-9,
            "{:?}",
            fits[0].plane
        );
        // 10 m: about 6°, a drone block's neighbours; not compared.
        let (heights, fits) = split(compare_with(None).heights(&with_base(10.0)));
        assert!(heights.is_empty() && fits.is_empty(), "{}", heights.len());
        // Beside plenty of points seen three times, two-view points are left out.
        let mut rec = with_base(60.0);
        let first_pair = rec.points.len();
        let more = scene_seen_by(&[3, 4, 5]).points;
        for (k, mut p) in more.into_iter().enumerate() {
            p.track = first_pair + k;
            rec.points.push(p);
        }
        let (heights, _) = split(compare_with(None).heights(&rec));
        assert!(heights.len() > 1000, "{}", heights.len());
        assert!(
            heights
                .iter()
                .all(|h| rec.points[h.track].observations.len() == 3)
        );
        // Without orientations no angle is known: not compared.
        let (heights, _) = split(compare_with(None).heights(&scene_seen_by(&[3, 4])));
        assert!(heights.is_empty());
    }

    #[test]
    fn a_planted_dome_and_height_scale_are_recovered_exactly() {
        // Points on a surface with relief (a ridge), missing it by every term at once.
        let mut rng = SeededRng::new(3);
        let points: Vec<Compared> = (0..400)
            .map(|track| {
                let (x, y) = (rng.uniform_range(0.0, 200.0), rng.uniform_range(0.0, 100.0));
                let surface = 5.0 + 0.01 * x + 3.0 * (-((y - 50.0) / 15.0).powi(2)).exp();
                Compared {
                    track,
                    position: Vector3::new(x, y, surface),
                    surface,
                    slope: [0.0; 2],
                }
            })
            .collect();
        let keep = vec![true; points.len()];
        // The regressors as `decompose` defines them, from a first pass.
        let first = decompose(1, &points, &keep).expect("fit");
        assert_eq!(first.plane, [0.0; 3]);
        let c = first.centroid;
        let (dome, scale) = (2e-6, 0.004);
        let relief_plane = {
            let kept: Vec<&Compared> = points.iter().collect();
            least_squares_of(
                &kept,
                3,
                &|p, row| {
                    row[0] = 1.0;
                    row[1] = p.position.x - c[0];
                    row[2] = p.position.y - c[1];
                },
                &|p| p.surface,
            )
            .expect("plane")
            .0
        };
        let missed: Vec<Compared> = points
            .iter()
            .map(|p| {
                let (dx, dy) = (p.position.x - c[0], p.position.y - c[1]);
                let above =
                    p.surface - (relief_plane[0] + relief_plane[1] * dx + relief_plane[2] * dy);
                let miss =
                    0.1 + 0.002 * dx - 0.001 * dy + dome * (dx * dx + dy * dy) + scale * above;
                Compared {
                    position: Vector3::new(p.position.x, p.position.y, p.surface + miss),
                    ..*p
                }
            })
            .collect();
        let f = decompose(1, &missed, &keep).expect("fit");
        let (d, ds) = f.dome.expect("dome");
        let (h, hs) = f.height_scale.expect("height scale");
        assert!((d - dome).abs() < 1e-12 && ds < 1e-12, "{d} ± {ds}");
        assert!((h - scale).abs() < 1e-9 && hs < 1e-9, "{h} ± {hs}");
    }
}
