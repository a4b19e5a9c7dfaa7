//! Extrema of the difference of Gaussians in one band: 3×3×3 neighbourhood test, sub-pixel and
//! sub-scale refinement by a quadratic fit (Lowe 2004, §4), contrast and edge rejection (§4.1).

use rayon::prelude::*;

use crate::pyramid::{BORDER, Band, BandStack, MAX_REFINE_STEPS, SCALE_SLACK};

/// A refined extremum in octave coordinates (pixel centres at integer indices).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Extremum {
    /// Integer layer of the Gaussian image to describe from.
    pub layer: usize,
    /// Refined column and row, octave pixels (global rows).
    pub x: f64,
    pub y: f64,
    /// Refined layer (fractional).
    pub s: f64,
    /// |DoG| at the refined extremum: the keypoint's response.
    pub contrast: f64,
    /// Octave row of the sample the refinement settled on.
    pub row: usize,
}

/// Thresholds of the extremum tests, in the units of the DoG.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ExtremumTests {
    pub layers: usize,
    /// Pre-test on the raw sample: half the contrast threshold (OpenCV).
    pub prefilter: f32,
    pub contrast: f64,
    pub edge_ratio: f64,
}

/// All refined extrema whose final sample lies in the band's core rows. Starting samples are
/// sought up to `MAX_REFINE_STEPS` rows beyond the core, so that each keypoint is found by exactly
/// the band that owns it, as if the octave were whole.
///
/// Scales are shared out the same way: extrema are sought in layers 1 ..= L + 1, and an octave
/// keeps refined scales below L + 0.5 + `SCALE_SLACK` (the last octave keeps all); refinement
/// may settle up to 0.5 + `SCALE_SLACK` layers beyond the searched layers. Searching L layers only,
/// as Lowe and OpenCV do, loses blobs whose scale falls half-way between two octaves: the
/// discrete maximum is then in layer L + 1 of one octave and layer 0 of the next, and neither is
/// searched.
pub(crate) fn find_extrema(
    stack: &BandStack,
    band: &Band,
    octave_height: usize,
    last_octave: bool,
    tests: &ExtremumTests,
) -> Vec<Extremum> {
    let width = stack.width();
    if width <= 2 * BORDER {
        return Vec::new();
    }
    let first = band
        .core
        .start
        .saturating_sub(MAX_REFINE_STEPS)
        .max(band.rows.start + 1);
    let last = (band.core.end + MAX_REFINE_STEPS).min(band.rows.end - 1);
    let rows: Vec<usize> = (first..last)
        .filter(|&y| y >= BORDER && y + BORDER < octave_height)
        .collect();
    let differences = tests.layers + 3;
    rows.par_iter()
        .map_init(
            // Per job: the three rows around y of every difference of Gaussians, and flags.
            || (vec![0.0f32; differences * 3 * width], vec![false; width]),
            |(dog_rows, flags), &y| {
                let mut found = Vec::new();
                let ly = y - stack.row0;
                for (i, out) in dog_rows.chunks_mut(width).enumerate() {
                    let (s, dy) = (i / 3, i % 3);
                    let (upper, lower) = (
                        stack.gauss[s + 1].row(ly + dy - 1),
                        stack.gauss[s].row(ly + dy - 1),
                    );
                    for ((o, a), b) in out.iter_mut().zip(upper).zip(lower) {
                        *o = a - b;
                    }
                }
                let rows_of = |s: usize| -> [&[f32]; 3] {
                    let at = |dy: usize| &dog_rows[(s * 3 + dy) * width..(s * 3 + dy + 1) * width];
                    [at(0), at(1), at(2)]
                };
                for s in 1..=tests.layers + 1 {
                    let (below, here, above) = (rows_of(s - 1), rows_of(s), rows_of(s + 1));
                    planar_extrema(here, tests.prefilter, flags);
                    for x in BORDER..width - BORDER {
                        if !flags[x] || !is_extremum(&below, &here, &above, x) {
                            continue;
                        }
                        if let Some(e) = refine(stack, x, ly, s, octave_height, tests)
                            && band.core.contains(&e.row)
                            && (e.s < tests.layers as f64 + 0.5 + SCALE_SLACK || last_octave)
                        {
                            found.push(e);
                        }
                    }
                }
                found
            },
        )
        .flatten_iter()
        .collect()
}

/// Flags the samples of the middle row of `rows` above `threshold` in magnitude that are ≥ (or ≤) their
/// 8 neighbours in the plane: the cheap, vectorised first cut of the extremum test. The first and
/// last sample are never flagged.
fn planar_extrema(rows: [&[f32]; 3], threshold: f32, flags: &mut [bool]) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked just above.
        return unsafe { planar_extrema_avx2(rows, threshold, flags) };
    }
    planar_extrema_portable(rows, threshold, flags)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn planar_extrema_avx2(rows: [&[f32]; 3], threshold: f32, flags: &mut [bool]) {
    planar_extrema_portable(rows, threshold, flags)
}

#[inline(always)]
fn planar_extrema_portable(rows: [&[f32]; 3], threshold: f32, flags: &mut [bool]) {
    let [up, row, down] = rows;
    let w = row.len();
    let n = w - 2;
    let centre = &row[1..n + 1];
    let (a, b, c) = (&up[..n], &up[1..n + 1], &up[2..n + 2]);
    let (d, e) = (&row[..n], &row[2..n + 2]);
    let (f, g, h) = (&down[..n], &down[1..n + 1], &down[2..n + 2]);
    let out = &mut flags[1..n + 1];
    // Plain comparisons (not f32::max, whose NaN rules block vectorisation).
    let hi = |p: f32, q: f32| if p > q { p } else { q };
    let lo = |p: f32, q: f32| if p < q { p } else { q };
    for i in 0..n {
        let v = centre[i];
        let max = hi(
            hi(hi(a[i], b[i]), hi(c[i], d[i])),
            hi(hi(e[i], f[i]), hi(g[i], h[i])),
        );
        let min = lo(
            lo(lo(a[i], b[i]), lo(c[i], d[i])),
            lo(lo(e[i], f[i]), lo(g[i], h[i])),
        );
        out[i] = (v > threshold && v >= max) || (v < -threshold && v <= min);
    }
    flags[0] = false;
    flags[w - 1] = false;
}

/// Whether the middle sample at column x of `here` is ≥ (or ≤) all 26 neighbours in space and
/// scale; each argument holds the three rows around it of one difference of Gaussians. The same
/// layer is known to pass (`planar_extrema`); the layers below and above are tested here.
#[inline]
fn is_extremum(below: &[&[f32]; 3], here: &[&[f32]; 3], above: &[&[f32]; 3], x: usize) -> bool {
    let v = here[1][x];
    let mut neighbours = [0.0f32; 18];
    for (k, rows) in [below, above].into_iter().enumerate() {
        for (r, row) in rows.iter().enumerate() {
            neighbours[k * 9 + r * 3..k * 9 + r * 3 + 3].copy_from_slice(&row[x - 1..=x + 1]);
        }
    }
    if v > 0.0 {
        neighbours.iter().all(|&n| v >= n)
    } else {
        neighbours.iter().all(|&n| v <= n)
    }
}

/// Quadratic refinement of the extremum at (x, y, s) (band-local row), moving to the neighbouring
/// sample while the offset exceeds half a sample; `None` when it leaves the valid domain, does not
/// settle, has too little contrast or lies on an edge.
fn refine(
    stack: &BandStack,
    x0: usize,
    y0: usize,
    s0: usize,
    octave_height: usize,
    tests: &ExtremumTests,
) -> Option<Extremum> {
    let (mut x, mut y, mut s) = (x0 as isize, y0 as isize, s0 as isize);
    let mut visited = [(0isize, 0isize, 0isize); MAX_REFINE_STEPS];
    for step_count in 0..MAX_REFINE_STEPS {
        visited[step_count] = (x, y, s);
        let d = |ds: isize, dy: isize, dx: isize| -> f64 {
            stack.dog((s + ds) as usize, (x + dx) as usize, (y + dy) as usize) as f64
        };
        let fit = QuadraticFit::at(&d);
        let mut offset = solve3(&fit.h, &fit.g)?.map(|v| -v);
        // One sample at most per step: the reach of refinement stays within MAX_REFINE_STEPS
        // samples, which bands of rows rely on.
        let mut step = offset.map(|o| (o.round() as isize).clamp(-1, 1));
        // Beyond the searched layers, the fit may still settle a little past the half-way point
        // (the neighbouring octave has its own, slightly different, fit of the same blob).
        let next_layer = s + step[2];
        if (next_layer < 1 || next_layer > tests.layers as isize + 1)
            && offset[2].abs() < 0.5 + SCALE_SLACK
        {
            step[2] = 0;
        }
        let next = (x + step[0], y + step[1], s + step[2]);
        let returning = walk_ends(&visited, step_count, step, next);
        if returning {
            offset = offset.map(|o| o.clamp(-0.5 - SCALE_SLACK, 0.5 + SCALE_SLACK));
        }
        if returning || step == [0, 0, 0] {
            return settle(&d, (x, y, s), &fit, offset, stack.row0, tests);
        }
        if offset.iter().any(|o| o.abs() > 1e6) {
            return None;
        }
        x += step[0];
        y += step[1];
        s += step[2];
        if !in_refinement_domain(stack, (x, y, s), octave_height, tests) {
            return None;
        }
    }
    None
}

/// Gradient and Hessian of the DoG at a sample, by central differences (x, y, s order).
struct QuadraticFit {
    g: [f64; 3],
    h: [[f64; 3]; 3],
}

impl QuadraticFit {
    /// The fit at the sample that `d(ds, dy, dx)` reads the DoG around.
    #[inline]
    fn at(d: &impl Fn(isize, isize, isize) -> f64) -> QuadraticFit {
        let v2 = 2.0 * d(0, 0, 0);
        let g = [
            0.5 * (d(0, 0, 1) - d(0, 0, -1)),
            0.5 * (d(0, 1, 0) - d(0, -1, 0)),
            0.5 * (d(1, 0, 0) - d(-1, 0, 0)),
        ];
        let dxx = d(0, 0, 1) + d(0, 0, -1) - v2;
        let dyy = d(0, 1, 0) + d(0, -1, 0) - v2;
        let dss = d(1, 0, 0) + d(-1, 0, 0) - v2;
        let dxy = 0.25 * (d(0, 1, 1) - d(0, 1, -1) - d(0, -1, 1) + d(0, -1, -1));
        let dxs = 0.25 * (d(1, 0, 1) - d(1, 0, -1) - d(-1, 0, 1) + d(-1, 0, -1));
        let dys = 0.25 * (d(1, 1, 0) - d(1, -1, 0) - d(-1, 1, 0) + d(-1, -1, 0));
        QuadraticFit {
            g,
            h: [[dxx, dxy, dxs], [dxy, dyy, dys], [dxs, dys, dss]],
        }
    }
}

/// Whether the walk ends at step `step_count` although its step to `next` is not zero: it
/// returns to a sample visited before, or is cornered.
///
/// An extremum half-way between samples can send the fit round a cycle of them (back and
/// forth, or round a square in space and scale): it is then found, between them. Half-way on
/// all three axes, the fit can wander round the cube of eight samples around the extremum
/// without coming back to one within the step budget: a last move that stays inside the cube
/// the walk has spanned ends it there, as a return does. (Only walks that would otherwise end
/// without a keypoint take this branch.)
fn walk_ends(
    visited: &[(isize, isize, isize); MAX_REFINE_STEPS],
    step_count: usize,
    step: [isize; 3],
    next: (isize, isize, isize),
) -> bool {
    let returning = step != [0, 0, 0] && visited[..step_count].contains(&next);
    let (lo, hi) = visited[..=step_count]
        .iter()
        .fold((next, next), |(lo, hi), v| {
            (
                (lo.0.min(v.0), lo.1.min(v.1), lo.2.min(v.2)),
                (hi.0.max(v.0), hi.1.max(v.1), hi.2.max(v.2)),
            )
        });
    let cornered = step_count + 1 == MAX_REFINE_STEPS
        && step != [0, 0, 0]
        && hi.0 - lo.0 <= 1
        && hi.1 - lo.1 <= 1
        && hi.2 - lo.2 <= 1;
    returning || cornered
}

/// The extremum the walk settled on at sample (x, y, s) (band-local row; `row0` the band's
/// first row) with `offset`, unless its contrast is too low or it lies on an edge.
fn settle(
    d: &impl Fn(isize, isize, isize) -> f64,
    (x, y, s): (isize, isize, isize),
    fit: &QuadraticFit,
    offset: [f64; 3],
    row0: usize,
    tests: &ExtremumTests,
) -> Option<Extremum> {
    let g = &fit.g;
    let contrast = d(0, 0, 0) + 0.5 * (g[0] * offset[0] + g[1] * offset[1] + g[2] * offset[2]);
    if contrast.abs() * (tests.layers as f64) < tests.contrast {
        return None;
    }
    let (dxx, dyy, dxy) = (fit.h[0][0], fit.h[1][1], fit.h[0][1]);
    let trace = dxx + dyy;
    let det = dxx * dyy - dxy * dxy;
    let r = tests.edge_ratio;
    if det <= 0.0 || trace * trace * r >= (r + 1.0) * (r + 1.0) * det {
        return None;
    }
    // The parabola through three samples of a peak is biased towards the nearest sample, by up
    // to 0.05 sample at coarse octaves (0.2 px at octave 2). A parabola through the logarithms
    // is exact for a Gaussian profile, which the DoG of a blob nearly is.
    let dx = log_parabola_peak(d(0, 0, -1), d(0, 0, 0), d(0, 0, 1)).unwrap_or(offset[0]);
    let dy = log_parabola_peak(d(0, -1, 0), d(0, 0, 0), d(0, 1, 0)).unwrap_or(offset[1]);
    Some(Extremum {
        layer: s as usize,
        x: x as f64 + dx,
        y: (y as usize + row0) as f64 + dy,
        s: s as f64 + offset[2],
        contrast: contrast.abs(),
        row: y as usize + row0,
    })
}

/// Whether sample (x, y, s) (band-local row) is one refinement may fit at: within the searched
/// layers, clear of the octave's border and inside the band's rows.
fn in_refinement_domain(
    stack: &BandStack,
    (x, y, s): (isize, isize, isize),
    octave_height: usize,
    tests: &ExtremumTests,
) -> bool {
    let global_y = y + stack.row0 as isize;
    !(s < 1
        || s > tests.layers as isize + 1
        || x < BORDER as isize
        || x >= (stack.width() - BORDER) as isize
        || global_y < BORDER as isize
        || global_y >= (octave_height - BORDER) as isize
        || y < 1
        || y >= stack.rows() as isize - 1)
}

/// Offset of the peak of the Gaussian through three equally spaced samples of one sign around
/// the middle one; `None` when the samples are not log-concave or the peak lies beyond them. The
/// middle sample need not be the largest: an extremum half-way between two samples is placed
/// right too.
fn log_parabola_peak(before: f64, at: f64, after: f64) -> Option<f64> {
    let sign = at.signum();
    let (b, a, c) = (before * sign, at * sign, after * sign);
    if !(b > 0.0 && c > 0.0 && a > 0.0) {
        return None;
    }
    let (lb, la, lc) = (b.ln(), a.ln(), c.ln());
    let curvature = lb - 2.0 * la + lc;
    if !(curvature < 0.0) {
        return None;
    }
    let offset = 0.5 * (lb - lc) / curvature;
    (offset.abs() <= 1.0).then_some(offset)
}

/// Solves the 3×3 system `h x = g` by Cramer's rule; `None` when `h` is singular.
fn solve3(h: &[[f64; 3]; 3], g: &[f64; 3]) -> Option<[f64; 3]> {
    let det3 = |m: &[[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let det = det3(h);
    let scale = h.iter().flatten().fold(0.0f64, |a, v| a.max(v.abs()));
    if !(det.abs() > 1e-12 * scale.powi(3)) {
        return None;
    }
    let mut out = [0.0; 3];
    for (c, o) in out.iter_mut().enumerate() {
        let mut m = *h;
        for r in 0..3 {
            m[r][c] = g[r];
        }
        *o = det3(&m) / det;
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_parabola_is_exact_on_a_gaussian() {
        for &centre in &[-0.49, -0.3, 0.0, 0.17, 0.45, 0.8, -0.95] {
            let g = |x: f64| -2.0 * (-(x - centre).powi(2) / (2.0 * 1.3f64.powi(2))).exp();
            let got = log_parabola_peak(g(-1.0), g(0.0), g(1.0)).unwrap();
            assert!((got - centre).abs() < 1e-12, "{got} vs {centre}");
        }
        assert!(log_parabola_peak(-1.0, 2.0, 1.0).is_none());
        assert!(log_parabola_peak(1.0, 1.0, 1.0).is_none());
    }

    #[test]
    fn solve3_recovers_a_solution_and_rejects_singular_systems() {
        let h = [[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]];
        let x = [0.3, -0.7, 1.1];
        let g: Vec<f64> = (0..3)
            .map(|r| (0..3).map(|c| h[r][c] * x[c]).sum())
            .collect();
        let got = solve3(&h, &[g[0], g[1], g[2]]).unwrap();
        for i in 0..3 {
            assert!((got[i] - x[i]).abs() < 1e-12);
        }
        let singular = [[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 1.0, 1.0]];
        assert!(solve3(&singular, &[1.0, 2.0, 3.0]).is_none());
        assert!(solve3(&[[0.0; 3]; 3], &[0.0; 3]).is_none());
    }
}
