//! Filling small holes of a DEM by interpolation, never by extrapolation: an empty cell is filled
//! when, along one of the four lines through it (row, column, two diagonals), measured cells on
//! both sides close a gap of at most `max_gap` cells. Its height is the mean of the linear
//! interpolations along those lines, weighted by the inverse gap length, so a planar surface is
//! filled exactly. Only measured heights are interpolated, so the result does not depend on the
//! order in which cells are visited.

use rayon::prelude::*;

use crate::Lattice;

/// The four lines through a cell, as one direction of each.
const LINES: [(isize, isize); 4] = [(1, 0), (0, 1), (1, 1), (1, -1)];

/// Fills holes of up to `max_gap` cells in `height` (NaN = empty) and marks them in `filled`.
pub fn fill_gaps(height: &mut [f32], filled: &mut [bool], lattice: &Lattice, max_gap: usize) {
    let (w, h) = (lattice.width(), lattice.height());
    let measured = height.to_vec();
    let measured = &measured;
    height
        .par_chunks_mut(w)
        .zip(filled.par_chunks_mut(w))
        .enumerate()
        .for_each(|(row, (h_row, f_row))| {
            for col in 0..w {
                if !measured[row * w + col].is_nan() {
                    continue;
                }
                if let Some(v) = interpolate(measured, (w, h), (col, row), max_gap) {
                    h_row[col] = v;
                    f_row[col] = true;
                }
            }
        });
}

/// The first measured cell from (col, row) stepping by `step`, within `max_gap` steps.
fn walk(
    measured: &[f32],
    (w, h): (usize, usize),
    (col, row): (usize, usize),
    step: (isize, isize),
    max_gap: usize,
) -> Option<(usize, f32)> {
    let (mut c, mut r) = (col as isize, row as isize);
    for d in 1..=max_gap {
        c += step.0;
        r += step.1;
        if c < 0 || r < 0 || c >= w as isize || r >= h as isize {
            return None;
        }
        let v = measured[r as usize * w + c as usize];
        if !v.is_nan() {
            return Some((d, v));
        }
    }
    None
}

fn interpolate(
    measured: &[f32],
    size: (usize, usize),
    cell: (usize, usize),
    max_gap: usize,
) -> Option<f32> {
    let (mut sum, mut weight) = (0.0f64, 0.0f64);
    for (dc, dr) in LINES {
        let Some((d1, v1)) = walk(measured, size, cell, (dc, dr), max_gap) else {
            continue;
        };
        let Some((d2, v2)) = walk(measured, size, cell, (-dc, -dr), max_gap) else {
            continue;
        };
        // The gap is the run of empty cells between the two measured ones.
        if d1 + d2 - 1 > max_gap {
            continue;
        }
        let (d1, d2) = (d1 as f64, d2 as f64);
        let v = (v1 as f64 * d2 + v2 as f64 * d1) / (d1 + d2);
        let wgt = 1.0 / (d1 + d2);
        sum += wgt * v;
        weight += wgt;
    }
    (weight > 0.0).then(|| (sum / weight) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_holes_in_a_plane_are_filled_exactly_large_ones_and_edges_are_not() {
        let l = Lattice::new(0.0, 20.0, 1.0, 20, 20).unwrap();
        let plane = |c: usize, r: usize| 5.0 + 0.3 * c as f32 - 0.2 * r as f32;
        let mut height: Vec<f32> = (0..400).map(|i| plane(i % 20, i / 20)).collect();
        // A 2 × 2 hole, a 6 × 6 hole, and an empty strip along the west edge.
        let small = [(5, 5), (6, 5), (5, 6), (6, 6)];
        for &(c, r) in &small {
            height[r * 20 + c] = f32::NAN;
        }
        for r in 10..16 {
            for c in 10..16 {
                height[r * 20 + c] = f32::NAN;
            }
        }
        for r in 0..20 {
            height[r * 20] = f32::NAN;
        }
        let mut filled = vec![false; 400];
        fill_gaps(&mut height, &mut filled, &l, 3);
        for &(c, r) in &small {
            assert!(filled[r * 20 + c]);
            assert!((height[r * 20 + c] - plane(c, r)).abs() < 1e-4);
        }
        // The middle of the large hole is more than 3 cells from its rim along every line.
        for r in 12..14 {
            for c in 12..14 {
                assert!(height[r * 20 + c].is_nan() && !filled[r * 20 + c]);
            }
        }
        // The edge strip has measured cells on one side only: no extrapolation.
        for r in 0..20 {
            assert!(height[r * 20].is_nan());
        }
        // Whatever was filled (also the large hole's corners, closed along a diagonal) lies on
        // the plane.
        for i in 0..400 {
            if filled[i] {
                assert!((height[i] - plane(i % 20, i / 20)).abs() < 1e-4);
            }
        }
    }
}
