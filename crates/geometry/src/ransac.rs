//! One generic robust estimator for every model: RANSAC with local optimisation (LO-RANSAC),
//! adaptive termination from the inlier ratio and the requested confidence, a seeded generator,
//! and two scores: MSAC (truncated quadratic at the threshold) or a threshold-free score that
//! marginalises the MSAC loss over noise scales up to a maximum (in the spirit of MAGSAC++).

use timesift_core::SeededRng;

use crate::GeometryError;

/// A model family that RANSAC can estimate.
pub trait Estimator {
    /// The estimated model.
    type Model: Clone;
    /// Name used in errors.
    const NAME: &'static str;
    /// Size of a minimal sample.
    fn min_samples(&self) -> usize;
    /// Number of data points.
    fn num_data(&self) -> usize;
    /// Models fitted to a minimal sample, appended to `models` (several when the minimal problem
    /// has several solutions; none when the sample is degenerate).
    fn fit_minimal(&self, sample: &[usize], models: &mut Vec<Self::Model>);
    /// A model fitted to many points (least squares), optionally weighted (each weight multiplies
    /// that point's squared residual); used by local optimisation and the final refit. `start` is the current best model, for iterative fits.
    fn fit_nonminimal(
        &self,
        indices: &[usize],
        weights: Option<&[f64]>,
        start: &Self::Model,
    ) -> Option<Self::Model>;
    /// Squared residual of data point `index`, in the units of the threshold squared.
    fn residual_sq(&self, model: &Self::Model, index: usize) -> f64;
}

/// How hypotheses are scored.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Scoring {
    /// Truncated quadratic loss at `max_error` (MSAC).
    Msac,
    /// Marginalised MSAC over noise scales σ ∈ (0, σ_max] with `max_error` = k·σ_max: per point
    /// loss `2u − u²` with `u = min(r / max_error, 1)`. No sharp threshold: `max_error` only needs
    /// to be a generous upper bound.
    Marginalized,
    /// Most inliers within `max_error`; among models with as many, the smallest sum of squared
    /// inlier residuals (COLMAP's support measure). Where a decision hangs on an inlier count
    /// (a pair verified with at least 15), this is the score that decides it: MSAC may prefer
    /// 14 tight inliers to 15 looser ones.
    InlierCount,
}

/// Options of [`ransac`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RansacOptions {
    /// Inlier threshold (MSAC) or upper bound of the error (marginalised), in residual units.
    pub max_error: f64,
    /// Probability of drawing at least one all-inlier sample before stopping.
    pub confidence: f64,
    /// Fewest iterations.
    pub min_iterations: usize,
    /// Most iterations.
    pub max_iterations: usize,
    /// Adaptive termination starts only once the best model has this many inliers; below, the
    /// search runs to `max_iterations`. For decisions that hinge on reaching a count (a pair is
    /// verified with 15 inliers): the confidence bound assumes the best model's inlier ratio is
    /// the true one, which is pessimistic exactly when the best is still short of the count.
    pub min_support: usize,
    /// Scoring function.
    pub scoring: Scoring,
    /// Local optimisation steps after each new best model (0 disables LO).
    pub local_optimization_steps: usize,
    /// Seed of the sampler.
    pub seed: u64,
}

impl Default for RansacOptions {
    fn default() -> Self {
        RansacOptions {
            max_error: 1.0,
            confidence: 0.9999,
            min_iterations: 10,
            max_iterations: 10_000,
            min_support: 0,
            scoring: Scoring::Msac,
            local_optimization_steps: 10,
            seed: 0x7153,
        }
    }
}

/// The result of [`ransac`].
#[derive(Debug, Clone)]
pub struct RansacResult<M> {
    /// The best model after local optimisation and a final refit.
    pub model: M,
    /// Inlier flag per data point (residual within `max_error`).
    pub inliers: Vec<bool>,
    /// Number of inliers.
    pub num_inliers: usize,
    /// Hypothesis iterations run.
    pub iterations: usize,
    /// Total loss of the model (lower is better).
    pub loss: f64,
}

/// Iterations needed to draw an all-inlier sample of size `m` with probability `confidence` when
/// a fraction `inlier_ratio` of the data are inliers.
pub fn required_iterations(inlier_ratio: f64, m: usize, confidence: f64) -> usize {
    let good = inlier_ratio.powi(m as i32);
    if good >= 1.0 {
        return 1;
    }
    if good <= f64::EPSILON {
        return usize::MAX;
    }
    let n = (1.0 - confidence).ln() / (1.0 - good).ln();
    if n.is_finite() {
        n.ceil().max(1.0) as usize
    } else {
        usize::MAX
    }
}

struct Scorer {
    threshold_sq: f64,
    threshold: f64,
    scoring: Scoring,
    /// Number of data, for [`Scoring::InlierCount`]: an inlier's loss is its squared residual
    /// over `threshold_sq · (n + 1)`, so all inliers together weigh less than one outlier.
    num_data: usize,
}

impl Scorer {
    fn point_loss(&self, r2: f64) -> f64 {
        match self.scoring {
            Scoring::Msac => (r2 / self.threshold_sq).min(1.0),
            Scoring::Marginalized => {
                let u = (r2.sqrt() / self.threshold).min(1.0);
                2.0 * u - u * u
            }
            Scoring::InlierCount => {
                if r2 <= self.threshold_sq {
                    r2 / (self.threshold_sq * (self.num_data + 1) as f64)
                } else {
                    1.0
                }
            }
        }
    }

    /// IRLS weight of a residual for the non-minimal fits: points near the threshold, where
    /// inliers and outliers mix, count little, so an outlier that slips under the threshold cannot
    /// pull a weakly conditioned model (weight 1 − r²/t², the negative slope of the MSAC loss, for MSAC; the
    /// marginalised loss's own weight otherwise).
    fn weight(&self, r2: f64) -> f64 {
        match self.scoring {
            Scoring::Msac | Scoring::InlierCount => 1.0 - (r2 / self.threshold_sq).min(1.0),
            Scoring::Marginalized => 1.0 - (r2.sqrt() / self.threshold).min(1.0),
        }
    }

    /// Loss and inlier count of a model; stops early once `bound` is exceeded.
    fn evaluate<E: Estimator>(&self, est: &E, model: &E::Model, bound: f64) -> (f64, usize) {
        let mut loss = 0.0;
        let mut inliers = 0;
        for i in 0..est.num_data() {
            let r2 = est.residual_sq(model, i);
            let r2 = if r2.is_finite() { r2 } else { f64::INFINITY };
            loss += self.point_loss(r2);
            if r2 <= self.threshold_sq {
                inliers += 1;
            }
            if loss > bound {
                return (f64::INFINITY, inliers);
            }
        }
        (loss, inliers)
    }

    fn inliers<E: Estimator>(&self, est: &E, model: &E::Model) -> (Vec<usize>, Vec<f64>) {
        let mut idx = Vec::new();
        let mut w = Vec::new();
        for i in 0..est.num_data() {
            let r2 = est.residual_sq(model, i);
            if r2 <= self.threshold_sq {
                idx.push(i);
                w.push(self.weight(r2));
            }
        }
        (idx, w)
    }
}

/// Robustly estimates a model. Fails when there are fewer data than a minimal sample or when no
/// hypothesis has as many inliers as a minimal sample.
pub fn ransac<E: Estimator>(
    est: &E,
    options: &RansacOptions,
) -> Result<RansacResult<E::Model>, GeometryError> {
    let n = est.num_data();
    let m = est.min_samples();
    if n < m {
        return Err(GeometryError::NotEnoughData {
            solver: E::NAME,
            needed: m,
            got: n,
        });
    }
    if !(options.max_error > 0.0) {
        return Err(GeometryError::Degenerate {
            solver: E::NAME,
            reason: "the RANSAC threshold must be positive",
        });
    }
    let scorer = Scorer {
        threshold_sq: options.max_error * options.max_error,
        threshold: options.max_error,
        scoring: options.scoring,
        num_data: n,
    };
    let mut rng = SeededRng::new(options.seed);
    let mut sample = vec![0usize; m];
    let mut models = Vec::new();
    let mut best: Option<(E::Model, f64, usize)> = None;
    let mut needed = options.max_iterations;
    let mut iterations = 0;

    while iterations < options.max_iterations.max(options.min_iterations)
        && (iterations < options.min_iterations || iterations < needed)
    {
        iterations += 1;
        rng.sample_distinct(n, &mut sample);
        models.clear();
        est.fit_minimal(&sample, &mut models);
        for model in models.drain(..) {
            let bound = best.as_ref().map_or(f64::INFINITY, |b| b.1);
            let (loss, count) = scorer.evaluate(est, &model, bound);
            if loss < bound {
                let (model, loss, count) =
                    local_optimization(est, &scorer, options, &mut rng, model, loss, count);
                best = Some((model, loss, count));
                if count >= options.min_support {
                    needed = required_iterations(count as f64 / n as f64, m, options.confidence)
                        .min(options.max_iterations);
                }
            }
        }
    }

    let Some((mut model, mut loss, mut count)) = best else {
        return Err(GeometryError::NoSolution {
            solver: E::NAME,
            reason: "no sample gave a model",
        });
    };
    // Final refit on all inliers, kept only when it does not worsen the loss.
    let (idx, w) = scorer.inliers(est, &model);
    if idx.len() > m {
        if let Some(refit) = est.fit_nonminimal(&idx, Some(&w), &model) {
            let (l, c) = scorer.evaluate(est, &refit, f64::INFINITY);
            if l <= loss {
                (model, loss, count) = (refit, l, c);
            }
        }
    }
    if count < m {
        return Err(GeometryError::NoSolution {
            solver: E::NAME,
            reason: "no model has as many inliers as a minimal sample",
        });
    }
    let inliers: Vec<bool> = (0..n)
        .map(|i| est.residual_sq(&model, i) <= scorer.threshold_sq)
        .collect();
    Ok(RansacResult {
        num_inliers: inliers.iter().filter(|b| **b).count(),
        model,
        inliers,
        iterations,
        loss,
    })
}

/// LO-RANSAC (Chum et al.): an inner RANSAC that fits non-minimal samples drawn from the current
/// inliers (which escapes shallow wrong basins), then iterated reweighted refits on all inliers
/// while the loss decreases.
fn local_optimization<E: Estimator>(
    est: &E,
    scorer: &Scorer,
    options: &RansacOptions,
    rng: &mut SeededRng,
    mut model: E::Model,
    mut loss: f64,
    mut count: usize,
) -> (E::Model, f64, usize) {
    if options.local_optimization_steps == 0 {
        return (model, loss, count);
    }
    let m = est.min_samples();
    let (idx, _) = scorer.inliers(est, &model);
    let inner_size = (7 * m).min(idx.len() / 2);
    if inner_size > m {
        let mut pick = vec![0usize; inner_size];
        let mut subset = vec![0usize; inner_size];
        let start = model.clone();
        for _ in 0..options.local_optimization_steps {
            rng.sample_distinct(idx.len(), &mut pick);
            for (s, &p) in subset.iter_mut().zip(&pick) {
                *s = idx[p];
            }
            let Some(candidate) = est.fit_nonminimal(&subset, None, &start) else {
                continue;
            };
            let (l, c) = scorer.evaluate(est, &candidate, loss);
            if l < loss {
                (model, loss, count) = (candidate, l, c);
            }
        }
    }
    for _ in 0..options.local_optimization_steps {
        let (idx, w) = scorer.inliers(est, &model);
        if idx.len() <= m {
            break;
        }
        let Some(refit) = est.fit_nonminimal(&idx, Some(&w), &model) else {
            break;
        };
        let (l, c) = scorer.evaluate(est, &refit, loss);
        if l < loss {
            (model, loss, count) = (refit, l, c);
        } else {
            break;
        }
    }
    (model, loss, count)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 2-D line y = a x + b as a toy model.
    struct Line<'a> {
        pts: &'a [(f64, f64)],
    }

    impl Estimator for Line<'_> {
        type Model = (f64, f64);
        const NAME: &'static str = "line";
        fn min_samples(&self) -> usize {
            2
        }
        fn num_data(&self) -> usize {
            self.pts.len()
        }
        fn fit_minimal(&self, s: &[usize], out: &mut Vec<(f64, f64)>) {
            let (p, q) = (self.pts[s[0]], self.pts[s[1]]);
            if (q.0 - p.0).abs() > 1e-12 {
                let a = (q.1 - p.1) / (q.0 - p.0);
                out.push((a, p.1 - a * p.0));
            }
        }
        fn fit_nonminimal(
            &self,
            idx: &[usize],
            _: Option<&[f64]>,
            _: &(f64, f64),
        ) -> Option<(f64, f64)> {
            let n = idx.len() as f64;
            let (mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0);
            for &i in idx {
                let (x, y) = self.pts[i];
                sx += x;
                sy += y;
                sxx += x * x;
                sxy += x * y;
            }
            let d = n * sxx - sx * sx;
            (d.abs() > 1e-12).then(|| {
                let a = (n * sxy - sx * sy) / d;
                (a, (sy - a * sx) / n)
            })
        }
        fn residual_sq(&self, m: &(f64, f64), i: usize) -> f64 {
            let (x, y) = self.pts[i];
            (y - m.0 * x - m.1).powi(2)
        }
    }

    /// 14 points exactly on y = 0 and 15 within ±0.45 of y = 10 + x / 2 (x in 0..14): with
    /// threshold 1, MSAC prefers the first line (loss 15 against 15 · 0.45² + 14), the inlier
    /// count the second.
    fn tight_few_and_loose_many() -> Vec<(f64, f64)> {
        let mut pts: Vec<(f64, f64)> = (0..14).map(|i| (i as f64, 0.0)).collect();
        pts.extend((0..15).map(|i| {
            let x = i as f64 * 14.0 / 15.0;
            (x, 10.0 + 0.5 * x + if i % 2 == 0 { 0.45 } else { -0.45 })
        }));
        pts
    }

    #[test]
    fn inlier_count_scoring_prefers_more_inliers_to_tighter_ones() {
        let pts = tight_few_and_loose_many();
        let run = |scoring| {
            ransac(
                &Line { pts: &pts },
                &RansacOptions {
                    max_error: 1.0,
                    scoring,
                    min_iterations: 500,
                    ..Default::default()
                },
            )
            .unwrap()
        };
        let msac = run(Scoring::Msac);
        assert_eq!(msac.num_inliers, 14);
        assert!(msac.model.0.abs() < 1e-9 && msac.model.1.abs() < 1e-9);
        let count = run(Scoring::InlierCount);
        assert_eq!(count.num_inliers, 15);
        assert!((count.model.0 - 0.5).abs() < 0.1 && (count.model.1 - 10.0).abs() < 0.5);
        assert!(count.inliers[14..].iter().all(|&b| b));
    }

    #[test]
    fn the_search_runs_its_whole_budget_while_short_of_min_support() {
        let pts = tight_few_and_loose_many();
        let run = |min_support| {
            ransac(
                &Line { pts: &pts },
                &RansacOptions {
                    max_error: 1.0,
                    max_iterations: 3000,
                    min_support,
                    ..Default::default()
                },
            )
            .unwrap()
        };
        // 14 of 29 inliers: the confidence bound stops after ~40 samples of two.
        assert!(run(0).iterations < 100, "{}", run(0).iterations);
        assert_eq!(run(30).iterations, 3000);
        assert!(run(10).iterations < 100);
    }

    #[test]
    fn line_with_half_outliers_is_found_and_iterations_adapt() {
        let mut rng = SeededRng::new(3);
        let pts: Vec<(f64, f64)> = (0..200)
            .map(|i| {
                let x = i as f64 * 0.1;
                if i % 2 == 0 {
                    (x, 2.0 * x - 1.0 + 0.01 * rng.normal())
                } else {
                    (x, rng.uniform_range(-50.0, 50.0))
                }
            })
            .collect();
        for scoring in [Scoring::Msac, Scoring::Marginalized, Scoring::InlierCount] {
            let r = ransac(
                &Line { pts: &pts },
                &RansacOptions {
                    max_error: 0.1,
                    scoring,
                    ..Default::default()
                },
            )
            .unwrap();
            assert!(
                (r.model.0 - 2.0).abs() < 1e-3 && (r.model.1 + 1.0).abs() < 1e-2,
                "{:?}",
                r.model
            );
            assert!(r.num_inliers >= 98);
            assert!(r.iterations < 200, "{} iterations", r.iterations);
        }
        assert_eq!(required_iterations(0.5, 2, 0.99), 17);
        assert!(ransac(&Line { pts: &pts[..1] }, &RansacOptions::default()).is_err());
    }
}
