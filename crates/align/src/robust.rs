//! Robust location and scale of a sample, for noise estimates that blunders must not move.

/// Median of |v − median(v)|; 0 for no values. Times 1.4826 it is the σ of a Gaussian sample.
pub(crate) fn median_abs_deviation(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let centre = median(values);
    let mut deviations: Vec<f64> = values.iter().map(|v| (v - centre).abs()).collect();
    median(&mut deviations)
}

/// The middle value (the upper of the two middle ones for an even count); `values` is
/// reordered. Panics on no values.
pub(crate) fn median(values: &mut [f64]) -> f64 {
    let mid = values.len() / 2;
    let (_, m, _) = values.select_nth_unstable_by(mid, f64::total_cmp);
    *m
}
