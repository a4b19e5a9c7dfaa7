//! The keypoint budget: keep the strongest responses, spread over the image.
//!
//! The image is cut into about `cells` square cells. A share `spread` of the budget is dealt out
//! first: each occupied cell keeps up to its part of that share (its strongest keypoints); the
//! rest of the budget goes to the strongest remaining keypoints wherever they are. A cell with
//! little texture cannot waste more than its part; a textured corner cannot take the whole budget
//! before every cell has had its turn. `spread = 0` keeps the strongest overall (OpenCV's
//! `nfeatures`), `spread = 1` spreads the whole budget.

/// Indices of the kept items: the dealt share strongest first, then the rest strongest first.
/// `points` are (x, y, response) in pixels of an image
/// of `width × height`; ties are broken by index so the choice is reproducible.
pub fn select_spread(
    points: &[(f64, f64, f32)],
    width: usize,
    height: usize,
    max: usize,
    cells: usize,
    spread: f64,
) -> Vec<usize> {
    let mut order: Vec<usize> = (0..points.len()).collect();
    let by_response =
        |a: &usize, b: &usize| points[*b].2.total_cmp(&points[*a].2).then_with(|| a.cmp(b));
    order.sort_by(by_response);
    if points.len() <= max || cells <= 1 || !(spread > 0.0) {
        order.truncate(max);
        return order;
    }
    let side = ((width * height) as f64 / cells as f64).sqrt().max(1.0);
    let columns = ((width as f64 / side).ceil() as usize).max(1);
    let rows = ((height as f64 / side).ceil() as usize).max(1);
    let cell_of = |i: usize| {
        let (x, y, _) = points[i];
        let c = ((x / side).max(0.0) as usize).min(columns - 1);
        let r = ((y / side).max(0.0) as usize).min(rows - 1);
        r * columns + c
    };
    let mut taken_in_cell = vec![0usize; columns * rows];
    let mut rank = vec![0usize; points.len()];
    for &i in &order {
        let cell = cell_of(i);
        rank[i] = taken_in_cell[cell];
        taken_in_cell[cell] += 1;
    }
    let occupied = taken_in_cell.iter().filter(|&&n| n > 0).count().max(1);
    let dealt = (spread.min(1.0) * max as f64).round() as usize;
    let part = dealt.div_ceil(occupied).max(1);
    // First the dealt share: each cell's strongest (up to its part), strongest first overall,
    // no more than `dealt` of them; then the strongest of the rest.
    let mut first = Vec::with_capacity(dealt);
    let mut rest = Vec::with_capacity(order.len());
    for &i in &order {
        if rank[i] < part && first.len() < dealt {
            first.push(i);
        } else {
            rest.push(i);
        }
    }
    first.extend(rest);
    first.truncate(max);
    first
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn a_textured_corner_does_not_take_the_whole_budget() {
        // 100 strong points in the top-left corner, 10 weak ones alone in 10 other cells of the
        // 4 × 4 grid (100 px cells).
        let mut points: Vec<(f64, f64, f32)> = (0..100)
            .map(|i| (1.0 + (i % 10) as f64, 1.0 + (i / 10) as f64, 1.0 + i as f32))
            .collect();
        points.extend((1..11).map(|c| {
            (
                50.0 + 100.0 * (c % 4) as f64,
                50.0 + 100.0 * (c / 4) as f64,
                0.01,
            )
        }));
        let kept = select_spread(&points, 400, 400, 20, 16, 1.0);
        assert_eq!(kept.len(), 20);
        assert!(kept.iter().filter(|&&i| i >= 100).count() == 10);
        // The corner's share went to its strongest points.
        assert!(kept.iter().filter(|&&i| i < 100).all(|&i| i >= 90));
        // Half the budget spread: 10 dealt over 11 occupied cells, one each in response order
        // (the corner's best, then 9 weak cells); the other 10 go to the strongest.
        let kept = select_spread(&points, 400, 400, 20, 16, 0.5);
        assert_eq!(kept.iter().filter(|&&i| i >= 100).count(), 9);
        // 6 dealt: the corner's best and 5 weak cells, then the 24 strongest of the rest.
        let kept = select_spread(&points, 400, 400, 30, 16, 0.2);
        assert_eq!(kept.iter().filter(|&&i| i >= 100).count(), 5);
        assert!(kept.iter().filter(|&&i| i < 100).all(|&i| i >= 75));
        // One cell, or nothing spread: the strongest overall.
        let kept = select_spread(&points, 400, 400, 20, 16, 0.0);
        assert!(kept.iter().all(|i| (80..100).contains(i)));
        let kept = select_spread(&points, 400, 400, 20, 1, 1.0);
        assert!(kept.iter().all(|i| (80..100).contains(i)));
    }

    #[test]
    fn a_small_spread_deals_only_its_share() {
        // 64 occupied cells of an 8 × 8 grid; cell 0 holds the 5 strongest points.
        let mut points: Vec<(f64, f64, f32)> = (0..5)
            .map(|i| (1.0 + i as f64, 1.0, 10.0 + i as f32))
            .collect();
        for c in 1..64 {
            points.push((
                50.0 * (c % 8) as f64 + 25.0,
                50.0 * (c / 8) as f64 + 25.0,
                1.0,
            ));
        }
        let kept = select_spread(&points, 400, 400, 10, 64, 0.5);
        // 5 dealt (one per cell, strongest cells first: cell 0's best, then 4 weak), then the
        // strongest of the rest: cell 0's other 4, then a weak one.
        assert_eq!(kept.iter().filter(|&&i| i < 5).count(), 5);
        let kept = select_spread(&points, 400, 400, 10, 64, 0.0);
        assert_eq!(kept.iter().filter(|&&i| i < 5).count(), 5);
        let kept = select_spread(&points, 400, 400, 10, 64, 1.0);
        assert_eq!(kept.iter().filter(|&&i| i < 5).count(), 1);
    }

    proptest! {
        #[test]
        fn keeps_min_of_budget_and_count_without_repeats(
            pts in proptest::collection::vec((0.0f64..640.0, 0.0f64..480.0, 0.0f32..1.0), 0..300),
            max in 0usize..400,
            cells in 1usize..64,
            spread in 0.0f64..1.0,
        ) {
            let kept = select_spread(&pts, 640, 480, max, cells, spread);
            prop_assert_eq!(kept.len(), max.min(pts.len()));
            let mut sorted = kept.clone();
            sorted.sort_unstable();
            sorted.dedup();
            prop_assert_eq!(sorted.len(), kept.len());
            // The single strongest point is always kept when anything is.
            if let Some(best) = (0..pts.len()).max_by(|&a, &b| pts[a].2.total_cmp(&pts[b].2).then(b.cmp(&a))) {
                if max > 0 { prop_assert!(kept.contains(&best)); }
            }
        }
    }
}
