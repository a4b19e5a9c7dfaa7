//! Where a refinement pass matches again at the finer scale.
//!
//! A plan that refines works on images at half the requested level and runs the usual passes
//! down to the requested level (pyramid scale 1); the refinement pass at scale 0 upsamples
//! those planes and matches again only where they are poor. Poor means one of:
//! - a high cost: the window found no good plane (a tree crown's flank, where every window of
//!   the coarser scale straddles crown and ground);
//! - a bent surface: the depth's second difference across neighbouring pixels, measured in the
//!   pixel's own footprint on the surface, is large. A plane seen by a pinhole bends by a
//!   negligible amount (`2 f (∂d/∂u / d)²` footprints per pixel², well under 0.01 for any view
//!   of a field), so a bend of a footprint or more is a crown, a boulder, an edge — where a
//!   window of the coarser scale spans more than one surface.
//!
//! Flat, well-textured ground is picked by neither and keeps the coarser plane: refinement
//! costs in proportion to the part of the image that needs it.

use crate::DenseError;
use crate::camera::WorkingCamera;
use crate::depth_map::DepthMap;
use crate::patchmatch::cost::WORST;

/// When a coarse pixel is matched again at the finer scale.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefineOptions {
    /// A coarse pixel whose matching cost is at least this (1 − NCC, plus the geometric term)
    /// and at least `above_median` more than the map's median cost is matched again.
    pub min_cost: f32,
    /// How far above the coarse map's median cost (over its matched pixels) a cost must be to
    /// count as high. 0.1: on `archival` (film, median costs 0.18–0.38) 1.1 times less CPU
    /// for the whole stage, median and p90 error within +0.01 GSD, completeness within −0.3
    /// point; the digital scenes' medians (about 0.2) leave the floor in charge.
    pub above_median: f32,
    /// A coarse pixel whose depth bends by at least this many footprints (second difference
    /// along a row or a column, divided by depth / focal length) is matched again.
    pub min_bend: f32,
    /// Coarse pixels within this many of a picked one (a square) are matched again too: a
    /// window of the coarser scale reaches that far into its neighbours.
    pub grow: usize,
}

impl Default for RefineOptions {
    fn default() -> Self {
        RefineOptions {
            min_cost: 0.3,
            above_median: 0.1,
            min_bend: 1.0,
            grow: 2,
        }
    }
}

impl RefineOptions {
    /// Checks every option's domain.
    pub fn validate(&self) -> Result<(), DenseError> {
        if !(self.min_cost > 0.0) || !(self.min_bend > 0.0) {
            return Err(DenseError::InvalidOption(
                "refine min_cost and min_bend: expected positive numbers".into(),
            ));
        }
        if !(self.above_median >= 0.0) {
            return Err(DenseError::InvalidOption(
                "refine above_median: expected a cost of 0 or more".into(),
            ));
        }
        if self.grow > 16 {
            return Err(DenseError::InvalidOption(
                "refine grow: expected at most 16 coarse pixels".into(),
            ));
        }
        Ok(())
    }
}

/// Per pixel of a `width × height` map (the finer scale), whether a refinement pass matches it
/// again, from the coarser map `coarse` seen through `coarse_camera` (its focal length turns
/// depths into footprints).
pub fn refine_selection(
    coarse: &DepthMap,
    coarse_camera: &WorkingCamera,
    width: usize,
    height: usize,
    options: &RefineOptions,
) -> Vec<bool> {
    let (cw, ch) = (coarse.width, coarse.height);
    if cw == 0 || ch == 0 || !coarse.is_consistent() {
        return vec![true; width * height];
    }
    let f = coarse_camera.f as f32;
    let depth = |x: usize, y: usize| coarse.depth[y * cw + x];
    // Bend along one direction through (x, y): None where a neighbour has no depth.
    let bend = |x: usize, y: usize, dx: usize, dy: usize| -> Option<f32> {
        if x < dx || y < dy || x + dx >= cw || y + dy >= ch {
            return None;
        }
        let (a, b, c) = (depth(x - dx, y - dy), depth(x, y), depth(x + dx, y + dy));
        (a > 0.0 && b > 0.0 && c > 0.0).then(|| (a - 2.0 * b + c).abs() * f / b)
    };
    let min_cost = options
        .min_cost
        .max(median_cost(&coarse.cost) + options.above_median);
    let mut picked = vec![false; cw * ch];
    for y in 0..ch {
        for x in 0..cw {
            let k = y * cw + x;
            picked[k] = coarse.cost[k] >= min_cost
                || bend(x, y, 1, 0).is_some_and(|b| b >= options.min_bend)
                || bend(x, y, 0, 1).is_some_and(|b| b >= options.min_bend);
        }
    }
    let grown = dilate(&picked, cw, ch, options.grow);
    let mut selected = vec![false; width * height];
    for y in 0..height {
        let cy = (y / 2).min(ch - 1);
        for x in 0..width {
            let cx = (x / 2).min(cw - 1);
            selected[y * width + x] = grown[cy * cw + cx];
        }
    }
    selected
}

/// The median of the costs of matched pixels (above 0 and below [`WORST`]); 0 when none is.
fn median_cost(costs: &[f32]) -> f32 {
    let mut matched: Vec<f32> = costs
        .iter()
        .copied()
        .filter(|&c| c > 0.0 && c < WORST)
        .collect();
    if matched.is_empty() {
        return 0.0;
    }
    let middle = matched.len() / 2;
    *matched.select_nth_unstable_by(middle, f32::total_cmp).1
}

/// `mask` grown by `radius` pixels in every direction (a square), rows then columns.
fn dilate(mask: &[bool], width: usize, height: usize, radius: usize) -> Vec<bool> {
    if radius == 0 {
        return mask.to_vec();
    }
    let mut rows = vec![false; mask.len()];
    for y in 0..height {
        let row = &mask[y * width..(y + 1) * width];
        for x in 0..width {
            let (a, b) = (x.saturating_sub(radius), (x + radius).min(width - 1));
            rows[y * width + x] = row[a..=b].iter().any(|&m| m);
        }
    }
    let mut out = vec![false; mask.len()];
    for y in 0..height {
        let (a, b) = (y.saturating_sub(radius), (y + radius).min(height - 1));
        for x in 0..width {
            out[y * width + x] = (a..=b).any(|yy| rows[yy * width + x]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(width: usize, height: usize, f: f64) -> WorkingCamera {
        WorkingCamera {
            width,
            height,
            f,
            cx: width as f64 / 2.0,
            cy: height as f64 / 2.0,
        }
    }

    /// A coarse map of the plane n·X + w = 0 seen by `camera`, with cost 0.1 everywhere.
    fn plane_map(camera: &WorkingCamera, n: [f64; 3], w: f64) -> DepthMap {
        let mut map = DepthMap::empty(camera.width, camera.height);
        for y in 0..camera.height {
            for x in 0..camera.width {
                let ray = camera.pixel_ray(x, y);
                let d = -w / (n[0] * ray.x + n[1] * ray.y + n[2] * ray.z);
                map.depth[y * camera.width + x] = d as f32;
                map.cost[y * camera.width + x] = 0.1;
            }
        }
        map
    }

    #[test]
    fn a_plane_is_not_refined_even_seen_obliquely() {
        let cam = camera(64, 48, 60.0);
        // Ground 50 m below a camera tilted 40° about its x axis.
        let (s, c) = 40f64.to_radians().sin_cos();
        let map = plane_map(&cam, [0.0, -c, -s], 50.0 * s.max(c));
        assert!(map.depth.iter().all(|&d| d > 0.0));
        let selected = refine_selection(&map, &cam, 128, 96, &RefineOptions::default());
        assert!(selected.iter().all(|&s| !s));
    }

    #[test]
    fn a_bump_high_costs_and_their_surroundings_are_refined() {
        let cam = camera(64, 48, 60.0);
        let mut map = plane_map(&cam, [0.0, 0.0, -1.0], 50.0);
        // A crown: 3 m up over a few pixels around (20, 20).
        for (x, y, h) in [(20, 20, 3.0), (19, 20, 1.5), (21, 20, 1.5), (20, 19, 1.5)] {
            map.depth[y * 64 + x] -= h;
        }
        // A poorly matched pixel far from it.
        map.cost[40 * 64 + 50] = 0.5;
        let options = RefineOptions::default();
        let selected = refine_selection(&map, &cam, 128, 96, &options);
        let at = |x: usize, y: usize| selected[y * 128 + x];
        // The bump and `grow` coarse pixels around it, at the fine scale.
        assert!(at(40, 40) && at(2 * 17, 2 * 20) && at(2 * 23 + 1, 2 * 22 + 1));
        assert!(!at(2 * 14, 2 * 20) && !at(2 * 20, 2 * 26));
        assert!(at(100, 80) && at(2 * 48, 2 * 38) && !at(2 * 45, 80));
        let count = selected.iter().filter(|&&s| s).count();
        // Two squares of (2 grow + 1 + a little) coarse pixels, four fine pixels each.
        assert!(count < 4 * 2 * 8 * 8, "{count}");
    }

    #[test]
    fn uniformly_high_costs_refine_only_their_outliers() {
        let cam = camera(64, 48, 60.0);
        let mut map = plane_map(&cam, [0.0, 0.0, -1.0], 50.0);
        // Film grain: every cost between 0.35 and 0.45, above the floor of 0.3.
        for (k, c) in map.cost.iter_mut().enumerate() {
            *c = 0.35 + 0.1 * ((k * 7919) % 101) as f32 / 100.0;
        }
        // One window that found no good plane.
        map.cost[20 * 64 + 30] = 0.9;
        let options = RefineOptions::default();
        let selected = refine_selection(&map, &cam, 128, 96, &options);
        let count = selected.iter().filter(|&&s| s).count();
        // The median is 0.40: costs of 0.50 and more are high; here only the outlier, grown.
        let side = 2 * (2 * options.grow + 1);
        assert_eq!(count, side * side, "{count} pixels matched again");
        assert!(selected[40 * 128 + 60]);
        // Where the median is low, the floor decides: a cost of 0.31 is high.
        let mut clean = plane_map(&cam, [0.0, 0.0, -1.0], 50.0);
        clean.cost[10 * 64 + 10] = 0.31;
        let selected = refine_selection(&clean, &cam, 128, 96, &options);
        assert_eq!(selected.iter().filter(|&&s| s).count(), side * side);
        assert!(selected[20 * 128 + 20]);
    }

    #[test]
    fn dilation_grows_a_square() {
        let mut mask = vec![false; 7 * 5];
        mask[2 * 7 + 3] = true;
        let grown = dilate(&mask, 7, 5, 1);
        let set: Vec<usize> = (0..35).filter(|&k| grown[k]).collect();
        assert_eq!(set, vec![9, 10, 11, 16, 17, 18, 23, 24, 25]);
    }
}
