//! Summary statistics of height differences, the figures users publish for stable areas: count,
//! mean, median, standard deviation, RMSE, NMAD, extremes and the 2.5/97.5 % quantiles.

use serde::{Deserialize, Serialize};

/// Scale that makes the median absolute deviation a consistent estimator of a normal σ.
pub const NMAD_SCALE: f64 = 1.4826;

/// Statistics of a set of values (NaN values ignored).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Statistics {
    /// Number of finite values.
    pub count: usize,
    /// Arithmetic mean.
    pub mean: f64,
    /// Median (mean of the two middle values for an even count).
    pub median: f64,
    /// Population standard deviation (divisor n, as numpy and xdem).
    pub std: f64,
    /// Root mean square (about zero).
    pub rmse: f64,
    /// Normalised median absolute deviation, 1.4826 · median(|x − median|).
    pub nmad: f64,
    /// Smallest value.
    pub min: f64,
    /// Largest value.
    pub max: f64,
    /// 2.5 % quantile (linear interpolation, numpy's default).
    pub p2_5: f64,
    /// 97.5 % quantile.
    pub p97_5: f64,
}

/// Statistics of the finite values; `None` when there is none.
pub fn statistics(values: impl IntoIterator<Item = f64>) -> Option<Statistics> {
    let mut v: Vec<f64> = values.into_iter().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
    let rmse = (v.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
    v.sort_unstable_by(f64::total_cmp);
    let median = quantile_sorted(&v, 0.5);
    let mut dev: Vec<f64> = v.iter().map(|x| (x - median).abs()).collect();
    dev.sort_unstable_by(f64::total_cmp);
    Some(Statistics {
        count: v.len(),
        mean,
        median,
        std: var.sqrt(),
        rmse,
        nmad: NMAD_SCALE * quantile_sorted(&dev, 0.5),
        min: v[0],
        max: v[v.len() - 1],
        p2_5: quantile_sorted(&v, 0.025),
        p97_5: quantile_sorted(&v, 0.975),
    })
}

/// Quantile `q` ∈ [0, 1] of sorted values, linear between order statistics (numpy "linear").
pub fn quantile_sorted(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let pos = q.clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let i = pos.floor() as usize;
    let frac = pos - i as f64;
    if i + 1 < sorted.len() {
        sorted[i] + frac * (sorted[i + 1] - sorted[i])
    } else {
        sorted[i]
    }
}

/// Median of values, which must be finite (NaN for an empty slice), without sorting the whole
/// slice.
pub fn median(values: &mut [f64]) -> f64 {
    let n = values.len();
    if n == 0 {
        return f64::NAN;
    }
    let (_, &mut upper, _) = values.select_nth_unstable_by(n / 2, f64::total_cmp);
    if n % 2 == 1 {
        upper
    } else {
        let lower = values[..n / 2]
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        0.5 * (lower + upper)
    }
}

/// NMAD of values about their median (values are reordered).
pub fn nmad(values: &mut [f64]) -> f64 {
    let m = median(values);
    for v in values.iter_mut() {
        *v = (*v - m).abs();
    }
    NMAD_SCALE * median(values)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn statistics_of_a_known_sample() {
        let s = statistics([1.0, 2.0, 3.0, 4.0, 100.0, f64::NAN]).expect("values");
        assert_eq!(s.count, 5);
        assert_eq!(s.median, 3.0);
        assert_eq!(s.mean, 22.0);
        // |x − 3| = 2 1 0 1 97 → median 1.
        assert_eq!(s.nmad, NMAD_SCALE);
        assert!((s.rmse - (10030.0f64 / 5.0).sqrt()).abs() < 1e-12);
        // deviations from the mean 22: −21 −20 −19 −18 78 → Σ² = 7610.
        assert!((s.std - (7610.0f64 / 5.0).sqrt()).abs() < 1e-12);
        assert_eq!((s.min, s.max), (1.0, 100.0));
        // numpy.quantile([1,2,3,4,100], 0.975) = 4 + 0.9 · 96.
        assert!((s.p97_5 - 90.4).abs() < 1e-12);
        let mut even = [4.0, 1.0, 3.0, 2.0];
        assert_eq!(median(&mut even), 2.5);
        assert!(statistics([f64::NAN]).is_none());
    }

    #[test]
    fn nmad_of_normal_samples_estimates_sigma() {
        // Deterministic normal quantiles: the NMAD of a perfect normal sample is σ.
        let sigma = 0.7;
        let n = 20001;
        let values: Vec<f64> = (1..=n)
            .map(|i| sigma * inverse_normal_cdf(i as f64 / (n + 1) as f64))
            .collect();
        let s = statistics(values).expect("values");
        assert!((s.nmad - sigma).abs() < 2e-3 * sigma, "{}", s.nmad);
        assert!((s.std - sigma).abs() < 2e-2 * sigma, "{}", s.std);
    }

    /// Acklam's rational approximation (relative error < 1.2e-9).
    fn inverse_normal_cdf(p: f64) -> f64 {
        let a = [
            -3.969683028665376e1,
            2.209460984245205e2,
            -2.759285104469687e2,
            1.38357751867269e2,
            -3.066479806614716e1,
            2.506628277459239,
        ];
        let b = [
            -5.447609879822406e1,
            1.615858368580409e2,
            -1.556989798598866e2,
            6.680131188771972e1,
            -1.328068155288572e1,
        ];
        let c = [
            -7.784894002430293e-3,
            -3.223964580411365e-1,
            -2.400758277161838,
            -2.549732539343734,
            4.374664141464968,
            2.938163982698783,
        ];
        let d = [
            7.784695709041462e-3,
            3.224671290700398e-1,
            2.445134137142996,
            3.754408661907416,
        ];
        let pl = 0.02425;
        if p < pl {
            let q = (-2.0 * p.ln()).sqrt();
            (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5])
                / ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0)
        } else if p <= 1.0 - pl {
            let q = p - 0.5;
            let r = q * q;
            (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q
                / (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1.0)
        } else {
            -inverse_normal_cdf(1.0 - p)
        }
    }
}
