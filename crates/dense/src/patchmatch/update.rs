//! One pixel's update in a checkerboard half-pass of ACMH (Xu & Tao, "Multi-Scale Geometric
//! Consistency Guided Multi-View Stereo", CVPR 2019, and its ACMH baseline), the PatchMatch
//! scheme of Galliani et al. ("Massively Parallel Multiview Stereopsis by Surface Normal
//! Diffusion", ICCV 2015) with Schönberger et al.'s probabilistic view selection (COLMAP, ECCV
//! 2016) made per pixel. A hypothesis is a plane `n·X + w = 0` in the reference camera's frame;
//! its cost against a source view is 1 − NCC of a window warped by the plane's homography.
//!
//! [`PassContext::update`] does, in order, each step a function of its own:
//! 1. `sample_candidates`: adaptive checkerboard sampling, the lowest-cost hypothesis of each
//!    of eight regions of the other colour (four near "V"s, four far strips);
//! 2. `score_candidates`: each candidate's cost against every source view;
//! 3. `select_views`: multi-hypothesis joint view selection, each view's likelihood from the
//!    candidates' costs (good below τ(t), bad above τ₂) times the prior of the neighbours'
//!    selections, sampled into per-view weights;
//! 4. `adopt_best_candidate`: the candidate of least weighted cost, adopted when it beats the
//!    current hypothesis under the same weights;
//! 5. `refine_randomly`: random and perturbed depths and normals tried greedily.
//!
//! Then `keep` writes the result (a hierarchy pass keeps the upsampled plane unless beaten by a
//! margin).
//!
//! Departures from the published code, each deliberate: the near "V" regions use only pixels
//! of the other colour (as OpenMVS does), so a half-pass reads nothing it writes; every region
//! picks its lowest-cost sample (the reference code picks the highest in one strip); absent
//! regions are skipped rather than scored 0; a pixel whose views all look bad falls back to
//! equal weights instead of NaN; every random draw comes from a generator seeded by the pixel,
//! so results do not depend on threads.

use timesift_core::SeededRng;

use super::board::{OtherHalf, PixelState};
use super::cost::{
    PlaneRow, PlaneWarp, RefCamera, RefWindow, SourceView, WORST, WindowShape, geometric_cost,
    ncc_cost, plane_depth, plane_offset,
};
use super::fast_exp;
use crate::image::{Mask, Plane};

/// Most source views per reference (one bit each in [`PixelState::views`]).
pub const MAX_SOURCES: usize = 32;

/// Candidate regions: four near "V"s (regions `0..NEAR_REGIONS`), then four far strips, as
/// (dx, dy) offsets. Every offset has odd |dx| + |dy|: the other colour.
const REGIONS: usize = 8;
/// The near "V" regions come first.
const NEAR_REGIONS: usize = 4;
const NEAR_UP: [(i64, i64); 7] = [
    (0, -1),
    (-1, -2),
    (1, -2),
    (-2, -3),
    (2, -3),
    (-3, -4),
    (3, -4),
];
const FAR_LEN: usize = 11;

fn region_offset(region: usize, k: usize) -> Option<(i64, i64)> {
    match region {
        0..NEAR_REGIONS => {
            let (dx, dy) = *NEAR_UP.get(k)?;
            Some(match region {
                0 => (dx, dy),
                1 => (dx, -dy),
                2 => (dy, dx),
                _ => (-dy, dx),
            })
        }
        NEAR_REGIONS..REGIONS => {
            if k >= FAR_LEN {
                return None;
            }
            let d = 3 + 2 * k as i64;
            Some(match region {
                4 => (0, -d),
                5 => (0, d),
                6 => (-d, 0),
                _ => (d, 0),
            })
        }
        _ => None,
    }
}

/// Samples per region.
fn region_len(region: usize) -> usize {
    if region < NEAR_REGIONS {
        NEAR_UP.len()
    } else {
        FAR_LEN
    }
}

/// Everything a half-pass needs, shared by every pixel.
pub struct PassContext<'a> {
    /// The NCC window.
    pub shape: &'a WindowShape,
    /// Reference intensities at the pass's scale.
    pub grey: &'a Plane,
    /// Reference usable pixels.
    pub mask: &'a Mask,
    /// Reference camera.
    pub k_ref: RefCamera,
    /// Source views.
    pub sources: Vec<SourceView<'a>>,
    /// Each source's part of the plane homographies ([`PlaneWarp::new`] of the source).
    pub warps: Vec<PlaneWarp>,
    /// Depth range.
    pub depth_range: (f32, f32),
    /// Weight of the geometric term (0 in photometric passes).
    pub geometric_weight: f32,
    /// Truncation of the geometric term, pixels.
    pub geometric_max_px: f32,
    /// Whether this is a hierarchy pass (detail restorer).
    pub hierarchy: bool,
    /// Relative depth perturbation of the refinement.
    pub depth_perturbation: f32,
    /// Normal perturbation of the refinement, radians.
    pub normal_perturbation: f32,
    /// Seed of this view and pass.
    pub seed: u64,
}

/// Per-thread scratch memory.
pub struct Scratch {
    window: RefWindow,
    costs: [[f32; MAX_SOURCES]; REGIONS],
    geometric: [[f32; MAX_SOURCES]; REGIONS],
}

impl Scratch {
    /// Scratch for windows of `shape`.
    pub fn new(shape: &WindowShape) -> Scratch {
        Scratch {
            window: RefWindow::new(shape),
            costs: [[WORST; MAX_SOURCES]; REGIONS],
            geometric: [[0.0; MAX_SOURCES]; REGIONS],
        }
    }
}

/// A hypothesis at one pixel.
#[derive(Debug, Clone, Copy)]
struct Plane3 {
    n: [f32; 3],
    w: f32,
    depth: f32,
}

/// View-selection schedule (ACMH): good-cost threshold τ(t) = 0.8 exp(−t²/90).
fn good_threshold(iteration: usize) -> f32 {
    0.8 * (-((iteration * iteration) as f32) / 90.0).exp()
}
/// A cost above this is bad (τ₂).
const BAD_COST: f32 = 1.2;
/// Confidence of a good cost: exp(−c² / 2β²), β = 0.3.
const TWO_BETA2: f32 = 0.18;
/// Draws of the Monte-Carlo view sampling.
const VIEW_DRAWS: usize = 15;
/// Weight of a neighbour that selected / did not select a view.
const PRIOR_SELECTED: f32 = 0.9;
const PRIOR_UNSELECTED: f32 = 0.1;
/// The detail restorer keeps the upsampled hypothesis unless a new one is better by this much.
const RESTORER_MARGIN: f32 = 0.1;
/// Views averaged for the cost of a fresh hypothesis (ACMH's top-k).
pub const INIT_TOP_K: usize = 4;

/// Seed of one pixel's generator in one iteration.
pub fn pixel_seed(seed: u64, iteration: usize, x: usize, y: usize) -> u64 {
    let mut h = seed ^ 0x9E37_79B9_7F4A_7C15;
    for v in [iteration as u64, x as u64, y as u64] {
        h = (h ^ v).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        h ^= h >> 29;
    }
    h
}

/// A random unit normal facing `ray` (Marsaglia's method).
pub fn random_normal(rng: &mut SeededRng, ray: &[f32; 3]) -> [f32; 3] {
    let (q1, q2, s) = loop {
        let q1 = rng.uniform_range(-1.0, 1.0) as f32;
        let q2 = rng.uniform_range(-1.0, 1.0) as f32;
        let s = q1 * q1 + q2 * q2;
        if s < 1.0 {
            break (q1, q2, s);
        }
    };
    let r = 2.0 * (1.0 - s).sqrt();
    let mut n = [q1 * r, q2 * r, 1.0 - 2.0 * s];
    if n[0] * ray[0] + n[1] * ray[1] + n[2] * ray[2] > 0.0 {
        n = [-n[0], -n[1], -n[2]];
    }
    n
}

/// `n` rotated by small random angles about the three axes (each uniform in ±`angle`); `n`
/// itself when the result would not face `ray`.
fn perturb_normal(rng: &mut SeededRng, n: &[f32; 3], ray: &[f32; 3], angle: f32) -> [f32; 3] {
    let a: [f32; 3] = std::array::from_fn(|_| rng.uniform_range(-1.0, 1.0) as f32 * angle);
    let (s0, c0) = a[0].sin_cos();
    let (s1, c1) = a[1].sin_cos();
    let (s2, c2) = a[2].sin_cos();
    // Rx, then Ry, then Rz.
    let v = [n[0], c0 * n[1] - s0 * n[2], s0 * n[1] + c0 * n[2]];
    let v = [c1 * v[0] + s1 * v[2], v[1], -s1 * v[0] + c1 * v[2]];
    let v = [c2 * v[0] - s2 * v[1], s2 * v[0] + c2 * v[1], v[2]];
    if v[0] * ray[0] + v[1] * ray[1] + v[2] * ray[2] < 0.0 {
        v
    } else {
        *n
    }
}

impl PassContext<'_> {
    fn in_range(&self, depth: f32) -> bool {
        depth >= self.depth_range.0 && depth <= self.depth_range.1
    }

    /// Photometric cost against source `j` at (u, v) of the plane whose row is `row`.
    #[inline]
    fn photometric(&self, window: &RefWindow, j: usize, row: &PlaneRow, u: f32, v: f32) -> f32 {
        let h = self.warps[j].homography(row);
        ncc_cost(self.shape, window, &self.sources[j], &h, u, v)
    }

    /// The plane's row of its homographies.
    #[inline]
    fn row(&self, p: &Plane3) -> PlaneRow {
        PlaneRow::new(&self.k_ref, &p.n, p.w)
    }

    /// Geometric term of a plane against source `j` (0 in photometric passes).
    #[inline]
    fn geometric(&self, j: usize, p: &Plane3, u: f32, v: f32) -> f32 {
        if self.geometric_weight == 0.0 {
            return 0.0;
        }
        geometric_cost(
            &self.sources[j],
            &self.k_ref,
            u,
            v,
            p.depth,
            self.geometric_max_px,
        )
    }

    /// The weighted cost of a plane over the views with a weight; once the views summed so
    /// far reach `bound`, that partial cost (at least `bound`). Every view's cost is ≥ 0, so
    /// the full cost could only be higher: a caller that keeps a plane only below `bound`
    /// decides as it would on the full cost, without the remaining views' windows.
    fn weighted(
        &self,
        window: &RefWindow,
        views: &ViewWeights,
        p: &Plane3,
        at: &PixelAt,
        bound: f32,
    ) -> f32 {
        let row = self.row(p);
        let mut sum = 0.0;
        for (j, &w) in views.weights.iter().enumerate().take(self.sources.len()) {
            if w > 0.0 {
                let c = self.photometric(window, j, &row, at.u, at.v)
                    + self.geometric_weight * self.geometric(j, p, at.u, at.v);
                sum += w * c;
                if sum / views.total >= bound {
                    break;
                }
            }
        }
        sum / views.total
    }

    /// The state of a fresh hypothesis (random, upsampled or carried over): its cost is the
    /// mean of its `INIT_TOP_K` best views, which become its selected views.
    pub fn initial_state(
        &self,
        scratch: &mut Scratch,
        x: usize,
        y: usize,
        n: [f32; 3],
        depth: f32,
    ) -> PixelState {
        let (u, v) = (x as f32 + 0.5, y as f32 + 0.5);
        let ray = self.k_ref.ray(u, v);
        let plane = Plane3 {
            n,
            w: plane_offset(&n, depth, &ray),
            depth,
        };
        let mut state = PixelState {
            n,
            w: plane.w,
            depth,
            cost: WORST,
            views: 0,
            start_cost: WORST,
        };
        if !scratch.window.fill(self.shape, self.grey, x, y) {
            return state;
        }
        let ns = self.sources.len();
        let row = self.row(&plane);
        let mut costs = [WORST; MAX_SOURCES];
        for (j, c) in costs.iter_mut().enumerate().take(ns) {
            let photo = self.photometric(&scratch.window, j, &row, u, v);
            *c = if photo < WORST {
                photo + self.geometric_weight * self.geometric(j, &plane, u, v)
            } else {
                WORST
            };
        }
        let mut sorted = costs;
        sorted[..ns].sort_by(f32::total_cmp);
        let valid = sorted[..ns].iter().take_while(|&&c| c < WORST).count();
        let k = valid.min(INIT_TOP_K);
        if k > 0 {
            state.cost = sorted[..k].iter().sum::<f32>() / k as f32;
            let kth = sorted[k - 1];
            for (j, &c) in costs.iter().enumerate().take(ns) {
                if c <= kth {
                    state.views |= 1 << j;
                }
            }
        }
        state.start_cost = state.cost;
        state
    }

    /// Updates pixel (x, y) of the colour being processed: ACMH's four steps, each below.
    pub fn update(
        &self,
        other: &OtherHalf<'_>,
        scratch: &mut Scratch,
        state: &mut PixelState,
        x: usize,
        y: usize,
        iteration: usize,
    ) {
        if !self.mask.at(x, y) || !scratch.window.fill(self.shape, self.grey, x, y) {
            return;
        }
        let (u, v) = (x as f32 + 0.5, y as f32 + 0.5);
        let at = PixelAt {
            x,
            y,
            u,
            v,
            ray: self.k_ref.ray(u, v),
        };
        let mut rng = SeededRng::new(pixel_seed(self.seed, iteration, x, y));
        let candidates = self.sample_candidates(other, &at);
        self.score_candidates(scratch, &candidates, &at);
        let views = self.select_views(other, scratch, &candidates, &at, iteration, &mut rng);
        let before = *state;
        let mut best = self.adopt_best_candidate(scratch, &candidates, &views, state, &at);
        self.refine_randomly(scratch, &views, &at, &mut rng, &mut best);
        self.keep(state, before, best);
    }

    /// Step 1, adaptive checkerboard sampling: the lowest-cost sample of each region of the
    /// other colour, as a plane at this pixel (none where the region has no hypothesis, or its
    /// plane faces away or leaves the depth range here).
    #[inline]
    fn sample_candidates(&self, other: &OtherHalf<'_>, at: &PixelAt) -> Candidates {
        let ray = &at.ray;
        let mut candidates: Candidates = [None; REGIONS];
        for (region, slot) in candidates.iter_mut().enumerate() {
            let Some(s) = lowest_cost_sample(other, region, at.x, at.y) else {
                continue;
            };
            let depth = plane_depth(&s.n, s.w, ray);
            let facing = s.n[0] * ray[0] + s.n[1] * ray[1] + s.n[2] * ray[2] < 0.0;
            if facing && self.in_range(depth) {
                *slot = Some(Plane3 {
                    n: s.n,
                    w: s.w,
                    depth,
                });
            }
        }
        candidates
    }

    /// Step 2: the photometric and geometric cost of every candidate against every source,
    /// into the scratch tables.
    #[inline]
    fn score_candidates(&self, scratch: &mut Scratch, candidates: &Candidates, at: &PixelAt) {
        for (r, cand) in candidates.iter().enumerate() {
            let Some(p) = cand else { continue };
            let row = self.row(p);
            for j in 0..self.sources.len() {
                scratch.costs[r][j] = self.photometric(&scratch.window, j, &row, at.u, at.v);
                scratch.geometric[r][j] = self.geometric(j, p, at.u, at.v);
            }
        }
    }

    /// Step 3, joint view selection: each view's likelihood from the candidates' costs, times
    /// the prior of the neighbours' selections, sampled into weights (equal weights when no
    /// view is likely).
    #[inline]
    fn select_views(
        &self,
        other: &OtherHalf<'_>,
        scratch: &Scratch,
        candidates: &Candidates,
        at: &PixelAt,
        iteration: usize,
        rng: &mut SeededRng,
    ) -> ViewWeights {
        let ns = self.sources.len();
        let tau = good_threshold(iteration);
        let (x, y) = (at.x as i64, at.y as i64);
        let neighbours: [Option<&PixelState>; 4] = [
            other.get(x, y - 1),
            other.get(x, y + 1),
            other.get(x - 1, y),
            other.get(x + 1, y),
        ];
        let mut probability = [0.0f32; MAX_SOURCES];
        let mut total_probability = 0.0;
        for (j, prob) in probability.iter_mut().enumerate().take(ns) {
            *prob = view_likelihood(scratch, candidates, j, tau) * neighbour_prior(&neighbours, j);
            total_probability += *prob;
        }
        let mut weights = [0.0f32; MAX_SOURCES];
        if total_probability > 0.0 {
            for _ in 0..VIEW_DRAWS {
                let pick = draw_view(&probability[..ns], total_probability, rng);
                // Rounding can leave the last view picked with zero probability: skip it.
                if probability[pick] > 0.0 {
                    weights[pick] += 1.0;
                }
            }
        }
        if weights.iter().all(|&w| w == 0.0) {
            weights[..ns].fill(1.0);
        }
        let total: f32 = weights.iter().sum();
        let mut selected = 0u32;
        for (j, &w) in weights.iter().enumerate() {
            if w > 0.0 {
                selected |= 1 << j;
            }
        }
        ViewWeights {
            weights,
            total,
            selected,
        }
    }

    /// Step 4: the best candidate under the view weights, adopted (with its selected views)
    /// when it beats the current hypothesis scored under the same weights.
    #[inline]
    fn adopt_best_candidate(
        &self,
        scratch: &Scratch,
        candidates: &Candidates,
        views: &ViewWeights,
        state: &mut PixelState,
        at: &PixelAt,
    ) -> Scored {
        let mut current = Scored {
            plane: Plane3 {
                n: state.n,
                w: state.w,
                depth: state.depth,
            },
            cost: f32::INFINITY,
        };
        let weighted_candidate = |r: usize| {
            let mut sum = 0.0;
            for (j, &w) in views.weights.iter().enumerate().take(self.sources.len()) {
                if w > 0.0 {
                    sum +=
                        w * (scratch.costs[r][j] + self.geometric_weight * scratch.geometric[r][j]);
                }
            }
            sum / views.total
        };
        if state.depth > 0.0 {
            current.cost = self.weighted(&scratch.window, views, &current.plane, at, f32::INFINITY);
        }
        let mut best: Option<(usize, f32)> = None;
        for (r, cand) in candidates.iter().enumerate() {
            if cand.is_none() {
                continue;
            }
            let f = weighted_candidate(r);
            if best.is_none_or(|(_, b)| f < b) {
                best = Some((r, f));
            }
        }
        if let Some((r, f)) = best
            && f < current.cost
            && let Some(p) = candidates[r]
        {
            current = Scored { plane: p, cost: f };
            state.views = views.selected;
        }
        current
    }

    /// Step 5, refinement: random and perturbed depths and normals tried greedily against the
    /// hypothesis kept so far.
    #[inline]
    fn refine_randomly(
        &self,
        scratch: &Scratch,
        views: &ViewWeights,
        at: &PixelAt,
        rng: &mut SeededRng,
        current: &mut Scored,
    ) {
        if !(current.plane.depth > 0.0) {
            return;
        }
        let ray = &at.ray;
        let (lo, hi) = self.depth_range;
        let d_rand = rng.uniform_range(lo as f64, hi as f64) as f32;
        let n_rand = random_normal(rng, ray);
        let rho = self.depth_perturbation;
        let base = current.plane;
        let d_pert = base.depth * (1.0 + rng.uniform_range(-1.0, 1.0) as f32 * rho);
        let n_pert = perturb_normal(rng, &base.n, ray, self.normal_perturbation);
        let trials = [
            (d_rand, base.n),
            (base.depth, n_rand),
            (d_rand, n_rand),
            (base.depth, n_pert),
            (d_pert, base.n),
        ];
        for (depth, n) in trials {
            if !self.in_range(depth) {
                continue;
            }
            let p = Plane3 {
                n,
                w: plane_offset(&n, depth, ray),
                depth,
            };
            let f = self.weighted(&scratch.window, views, &p, at, current.cost);
            if f < current.cost {
                *current = Scored { plane: p, cost: f };
            }
        }
    }

    /// Writes the hypothesis kept into the pixel's state; a hierarchy pass (the detail
    /// restorer) keeps the upsampled one unless the new one is better by a margin.
    #[inline]
    fn keep(&self, state: &mut PixelState, before: PixelState, kept: Scored) {
        if !kept.cost.is_finite() {
            return;
        }
        if self.hierarchy && !(kept.cost < before.start_cost - RESTORER_MARGIN) {
            *state = before;
            return;
        }
        state.n = kept.plane.n;
        state.w = kept.plane.w;
        state.depth = kept.plane.depth;
        state.cost = kept.cost;
    }
}

/// The pixel being updated: its indices, its centre and the viewing ray through it.
struct PixelAt {
    x: usize,
    y: usize,
    u: f32,
    v: f32,
    ray: [f32; 3],
}

/// One candidate plane per region (none where the region offers no usable one).
type Candidates = [Option<Plane3>; REGIONS];

/// A hypothesis with its weighted cost.
#[derive(Clone, Copy)]
struct Scored {
    plane: Plane3,
    cost: f32,
}

/// The views a pixel's candidates are scored against: a weight per source (how often the
/// sampling drew it), their sum, and the drawn views as bits.
struct ViewWeights {
    weights: [f32; MAX_SOURCES],
    total: f32,
    selected: u32,
}

/// The other colour's sample of `region` around (x, y) with the lowest cost and a hypothesis.
#[inline]
fn lowest_cost_sample<'o>(
    other: &'o OtherHalf<'_>,
    region: usize,
    x: usize,
    y: usize,
) -> Option<&'o PixelState> {
    let mut best: Option<&PixelState> = None;
    for k in 0..region_len(region) {
        let Some((dx, dy)) = region_offset(region, k) else {
            break;
        };
        let Some(s) = other.get(x as i64 + dx, y as i64 + dy) else {
            // Strips stop at the border; V samples beyond it are skipped.
            if region >= NEAR_REGIONS {
                break;
            }
            continue;
        };
        if s.depth > 0.0 && best.is_none_or(|b| s.cost < b.cost) {
            best = Some(s);
        }
    }
    best
}

/// ACMH's likelihood of view `j`: the mean confidence of its good costs among the candidates
/// when more than two are good and fewer than three bad, a floor when few are bad, else 0.
#[inline]
fn view_likelihood(scratch: &Scratch, candidates: &Candidates, j: usize, tau: f32) -> f32 {
    let (mut good, mut good_sum, mut bad) = (0, 0.0f32, 0);
    for (r, cand) in candidates.iter().enumerate() {
        if cand.is_none() {
            continue;
        }
        let c = scratch.costs[r][j];
        if c < tau {
            good += 1;
            good_sum += fast_exp::exp_neg(-c * c / TWO_BETA2);
        } else if c > BAD_COST {
            bad += 1;
        }
    }
    if good > 2 && bad < 3 {
        good_sum / good as f32
    } else if bad < 3 {
        fast_exp::exp_neg(-tau * tau / 0.32)
    } else {
        0.0
    }
}

/// The prior of view `j` from the four neighbours' selections.
#[inline]
fn neighbour_prior(neighbours: &[Option<&PixelState>; 4], j: usize) -> f32 {
    neighbours
        .iter()
        .flatten()
        .map(|s| {
            if s.views & (1 << j) != 0 {
                PRIOR_SELECTED
            } else {
                PRIOR_UNSELECTED
            }
        })
        .sum()
}

/// One Monte-Carlo draw of a view in proportion to `probability` (summing to `total`); the
/// last view when rounding leaves the draw past the end.
#[inline]
fn draw_view(probability: &[f32], total: f32, rng: &mut SeededRng) -> usize {
    let mut target = rng.uniform() as f32 * total;
    for (j, &p) in probability.iter().enumerate() {
        if p > 0.0 && target < p {
            return j;
        }
        target -= p;
    }
    probability.len() - 1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regions_sample_only_the_other_colour() {
        for region in 0..REGIONS {
            for k in 0..region_len(region) {
                let (dx, dy) = region_offset(region, k).unwrap();
                assert_eq!((dx + dy).rem_euclid(2), 1, "region {region} sample {k}");
            }
            assert!(region_offset(region, region_len(region)).is_none());
        }
    }

    #[test]
    fn random_normals_are_unit_and_face_the_ray() {
        let mut rng = SeededRng::new(3);
        let ray = [0.3, -0.2, 1.0];
        for _ in 0..200 {
            let n = random_normal(&mut rng, &ray);
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            assert!((len - 1.0).abs() < 1e-5);
            assert!(n[0] * ray[0] + n[1] * ray[1] + n[2] * ray[2] <= 0.0);
            let p = perturb_normal(&mut rng, &n, &ray, 0.05);
            let cos = n[0] * p[0] + n[1] * p[1] + n[2] * p[2];
            assert!(cos > (0.05f32 * 3f32.sqrt() * 1.01).cos());
        }
    }
}
