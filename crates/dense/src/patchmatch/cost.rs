//! The matching cost of a plane hypothesis at a reference pixel against one source view:
//! bilateral-weighted NCC over a sparse window warped by the plane-induced homography, and the
//! geometric-consistency term (forward–backward reprojection through the source's depth map).
//!
//! Everything here runs in the innermost loop: f32, no allocation, the reference half of the
//! NCC computed once per pixel ([`RefWindow`]) and reused for every hypothesis and source.

use super::fast_exp;
use crate::camera::WorkingCamera;
use crate::image::{Mask, Plane};

/// Cost of a failed evaluation (projection outside the source, no texture): the worst NCC cost.
pub const WORST: f32 = 2.0;

/// Least weighted intensity variance of a window (intensities 0–1): below it NCC is noise.
const MIN_VARIANCE: f32 = 1e-7;

/// Most samples of a window (the options keep `(2 radius / step + 1)²` below it).
pub const MAX_WINDOW: usize = 128;
/// Lanes of the accumulations: sample counts are padded to a multiple of it with zero weights,
/// so the sums have a fixed order whatever the instruction set.
const LANES: usize = 8;

/// Window offsets and spatial weights of the sparse NCC window, padded to a multiple of
/// `LANES` samples (padding: offset 0, weight 0).
#[derive(Debug, Clone)]
pub struct WindowShape {
    /// dx per sample.
    pub dx: Vec<f32>,
    /// dy per sample.
    pub dy: Vec<f32>,
    /// Spatial part of the bilateral weight per sample (0 for padding).
    pub spatial: Vec<f32>,
    /// Samples that are not padding.
    pub samples: usize,
    /// 1 / (2 σ_color²).
    pub inv_two_sigma_color2: f32,
    /// The first and last offset along either axis (the window's bounding square).
    pub extent: (f32, f32),
}

impl WindowShape {
    /// Samples at `-radius..=radius` by `step` in both directions (the sparse window of ACMH and
    /// COLMAP) but for the grid's four corners, spatial weight `exp(-r² / 2σs²)`. Fails beyond
    /// [`MAX_WINDOW`] samples. The corners are the samples farthest from the centre and least
    /// weighted (0.37 of the centre's with the default σs = radius); without them the default
    /// window's 36 samples are 32, four full lanes of eight where 36 took five.
    pub fn new(
        radius: usize,
        step: usize,
        sigma_spatial: f32,
        sigma_color: f32,
    ) -> Option<WindowShape> {
        let r = radius as i64;
        let ticks: Vec<f32> = (-r..=r).step_by(step.max(1)).map(|d| d as f32).collect();
        let (first, last) = (ticks[0], ticks[ticks.len() - 1]);
        let corner = |x: f32, y: f32| {
            ticks.len() >= 3 && (x == first || x == last) && (y == first || y == last)
        };
        let samples = ticks.len() * ticks.len() - if ticks.len() >= 3 { 4 } else { 0 };
        let padded = samples.div_ceil(LANES) * LANES;
        if padded > MAX_WINDOW {
            return None;
        }
        let (mut dx, mut dy, mut spatial) = (
            Vec::with_capacity(padded),
            Vec::with_capacity(padded),
            Vec::with_capacity(padded),
        );
        for &y in &ticks {
            for &x in &ticks {
                if corner(x, y) {
                    continue;
                }
                dx.push(x);
                dy.push(y);
                spatial.push((-(x * x + y * y) / (2.0 * sigma_spatial * sigma_spatial)).exp());
            }
        }
        dx.resize(padded, 0.0);
        dy.resize(padded, 0.0);
        spatial.resize(padded, 0.0);
        Some(WindowShape {
            dx,
            dy,
            spatial,
            samples,
            extent: (first, last),
            inv_two_sigma_color2: 1.0 / (2.0 * sigma_color * sigma_color),
        })
    }

    /// Samples including padding.
    pub fn len(&self) -> usize {
        self.dx.len()
    }

    /// Whether the window is empty (never, for a valid shape).
    pub fn is_empty(&self) -> bool {
        self.dx.is_empty()
    }
}

/// The reference half of the NCC at one pixel: bilateral weights and intensities.
#[derive(Debug, Clone)]
pub struct RefWindow {
    /// Bilateral weights, normalised to sum to 1 over the samples inside the image (0 for
    /// samples outside it and for padding).
    pub weight: Vec<f32>,
    /// Intensity relative to the window's centre pixel (keeps the sums accurate in f32).
    pub value: Vec<f32>,
    /// Weighted variance of the reference intensities.
    pub variance: f32,
}

impl RefWindow {
    /// Scratch for windows of `shape`.
    pub fn new(shape: &WindowShape) -> RefWindow {
        RefWindow {
            weight: vec![0.0; shape.len()],
            value: vec![0.0; shape.len()],
            variance: 0.0,
        }
    }

    /// Fills the window at pixel (i, j) of `grey`; samples outside the image get no weight
    /// (the window is truncated at the border rather than filled with repeated edge pixels,
    /// which would match anything). Returns whether the window has texture enough for NCC.
    pub fn fill(&mut self, shape: &WindowShape, grey: &Plane, i: usize, j: usize) -> bool {
        #[cfg(target_arch = "x86_64")]
        if std::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, checked just above.
            return unsafe { self.fill_avx2(shape, grey, i, j) };
        }
        self.fill_portable(shape, grey, i, j)
    }

    /// [`RefWindow::fill_portable`] with the weights eight lanes wide in AVX2: the same
    /// operations in the same order (the exponential is [`fast_exp::exp_neg`] step for step),
    /// so the same bits (a test checks it).
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn fill_avx2(&mut self, shape: &WindowShape, grey: &Plane, i: usize, j: usize) -> bool {
        use std::arch::x86_64::*;
        let n = shape.len();
        if n % LANES != 0
            || self.weight.len() < n
            || self.value.len() < n
            || shape.spatial.len() < n
        {
            return self.fill_portable(shape, grey, i, j);
        }
        self.read_window(shape, grey, i, j);
        let splat = |x: f32| _mm256_set1_ps(x);
        let k_color = splat(shape.inv_two_sigma_color2);
        let mut sum_w = splat(0.0);
        for k0 in (0..n).step_by(LANES) {
            // SAFETY: k0 + LANES ≤ n ≤ the lengths of the three vectors, checked above.
            unsafe {
                let r = _mm256_loadu_ps(self.value.as_ptr().add(k0));
                let arg = _mm256_mul_ps(_mm256_sub_ps(splat(0.0), _mm256_mul_ps(r, r)), k_color);
                let e = fast_exp::exp_neg_avx2(arg);
                let sp = _mm256_loadu_ps(shape.spatial.as_ptr().add(k0));
                let inside = _mm256_loadu_ps(self.weight.as_ptr().add(k0));
                let wt = _mm256_mul_ps(inside, _mm256_mul_ps(sp, e));
                _mm256_storeu_ps(self.weight.as_mut_ptr().add(k0), wt);
                sum_w = _mm256_add_ps(sum_w, wt);
            }
        }
        let inv = splat(1.0 / sum_lanes_avx2(sum_w));
        let (mut mean, mut second) = (splat(0.0), splat(0.0));
        for k0 in (0..n).step_by(LANES) {
            // SAFETY: as above.
            unsafe {
                let wt = _mm256_mul_ps(_mm256_loadu_ps(self.weight.as_ptr().add(k0)), inv);
                _mm256_storeu_ps(self.weight.as_mut_ptr().add(k0), wt);
                let r = _mm256_loadu_ps(self.value.as_ptr().add(k0));
                let wr = _mm256_mul_ps(wt, r);
                mean = _mm256_add_ps(mean, wr);
                second = _mm256_add_ps(second, _mm256_mul_ps(wr, r));
            }
        }
        let mean = sum_lanes_avx2(mean);
        self.variance = sum_lanes_avx2(second) - mean * mean;
        self.variance > MIN_VARIANCE
    }

    /// The window's intensities relative to its centre pixel (0 outside the image), and in
    /// `weight` 1 inside the image and 0 outside (the reads are scalar: the offsets are
    /// arbitrary).
    #[inline(always)]
    fn read_window(&mut self, shape: &WindowShape, grey: &Plane, i: usize, j: usize) {
        let centre = grey.at(i, j);
        let (w, h) = (grey.width as i64, grey.height as i64);
        let n = shape.len();
        for k in 0..n {
            let x = i as i64 + shape.dx[k] as i64;
            let y = j as i64 + shape.dy[k] as i64;
            let inside = x >= 0 && y >= 0 && x < w && y < h;
            self.value[k] = if inside {
                grey.at(x as usize, y as usize) - centre
            } else {
                0.0
            };
            self.weight[k] = if inside { 1.0 } else { 0.0 };
        }
    }

    /// The fill in plain Rust; its sums run in `LANES` lanes like the AVX2 version's.
    fn fill_portable(&mut self, shape: &WindowShape, grey: &Plane, i: usize, j: usize) -> bool {
        self.read_window(shape, grey, i, j);
        let n = shape.len();
        let k_color = shape.inv_two_sigma_color2;
        let mut sum_w = [0.0f32; LANES];
        for k in 0..n {
            let r = self.value[k];
            let wt =
                self.weight[k] * (shape.spatial[k] * fast_exp::exp_neg((0.0 - r * r) * k_color));
            self.weight[k] = wt;
            sum_w[k % LANES] += wt;
        }
        let inv = 1.0 / sum_lanes(&sum_w);
        let (mut mean, mut second) = ([0.0f32; LANES], [0.0f32; LANES]);
        for k in 0..n {
            let wt = self.weight[k] * inv;
            self.weight[k] = wt;
            let wr = wt * self.value[k];
            mean[k % LANES] += wr;
            second[k % LANES] += wr * self.value[k];
        }
        let mean = sum_lanes(&mean);
        self.variance = sum_lanes(&second) - mean * mean;
        self.variance > MIN_VARIANCE
    }
}

/// A source view at the pass's scale, in the reference camera's frame.
pub struct SourceView<'a> {
    /// Grey intensities.
    pub grey: &'a Plane,
    /// Usable pixels.
    pub mask: &'a Mask,
    /// The source's camera at this scale.
    pub camera: WorkingCamera,
    /// `src_from_ref` rotation, row-major.
    pub r: [f32; 9],
    /// `src_from_ref` translation.
    pub t: [f32; 3],
    /// The source's depth map for the geometric term, with the camera of its scale.
    pub depth: Option<(&'a [f32], WorkingCamera)>,
}

/// The reference camera at the pass's scale, as f32 for the inner loops.
#[derive(Debug, Clone, Copy)]
pub struct RefCamera {
    /// Focal length.
    pub f: f32,
    /// Principal point.
    pub cx: f32,
    /// Principal point.
    pub cy: f32,
}

impl RefCamera {
    /// Of a working camera.
    pub fn of(c: &WorkingCamera) -> RefCamera {
        RefCamera {
            f: c.f as f32,
            cx: c.cx as f32,
            cy: c.cy as f32,
        }
    }

    /// The ray (z = 1) through continuous pixel coordinates (u, v).
    #[inline]
    pub fn ray(&self, u: f32, v: f32) -> [f32; 3] {
        [(u - self.cx) / self.f, (v - self.cy) / self.f, 1.0]
    }
}

#[inline]
fn dot(a: &[f32; 3], b: &[f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The plane-independent part of the homographies from reference pixels to one source's
/// pixels: `H = K_s (R − t nᵀ / w) K_r⁻¹ = A − b cᵀ` with `A = K_s R K_r⁻¹` and `b = K_s t`
/// fixed for a pass, and `cᵀ = nᵀ K_r⁻¹ / w` ([`PlaneRow`]) fixed for a plane. A pixel scores
/// each of its candidate planes against every source: the split turns each homography into
/// nine multiply–adds.
#[derive(Debug, Clone, Copy)]
pub struct PlaneWarp {
    /// `K_s R K_r⁻¹`, row-major.
    a: [f32; 9],
    /// `K_s t`.
    b: [f32; 3],
}

/// The plane's part of its homographies, `cᵀ = nᵀ K_r⁻¹ / w`, shared by every source.
#[derive(Debug, Clone, Copy)]
pub struct PlaneRow([f32; 3]);

impl PlaneRow {
    /// Of the plane `n·X + w = 0` (reference camera frame).
    #[inline]
    pub fn new(k_ref: &RefCamera, n: &[f32; 3], w: f32) -> PlaneRow {
        // nᵀ K_r⁻¹, with K_r⁻¹ = [[1/f, 0, -cx/f], [0, 1/f, -cy/f], [0, 0, 1]].
        let (fi, inv_w) = (1.0 / k_ref.f, 1.0 / w);
        PlaneRow([
            n[0] * fi * inv_w,
            n[1] * fi * inv_w,
            (n[2] - (n[0] * k_ref.cx + n[1] * k_ref.cy) * fi) * inv_w,
        ])
    }
}

impl PlaneWarp {
    /// Of a source view seen from the reference camera `k_ref`.
    pub fn new(src: &SourceView<'_>, k_ref: &RefCamera) -> PlaneWarp {
        let (r, t) = (&src.r, &src.t);
        // R K_r⁻¹.
        let (fi, cx, cy) = (1.0 / k_ref.f, k_ref.cx, k_ref.cy);
        let mut m = [0.0f32; 9];
        for row in 0..3 {
            let (r0, r1, r2) = (r[row * 3], r[row * 3 + 1], r[row * 3 + 2]);
            m[row * 3] = r0 * fi;
            m[row * 3 + 1] = r1 * fi;
            m[row * 3 + 2] = r2 - (r0 * cx + r1 * cy) * fi;
        }
        // K_s (·), with K_s = [[f, 0, cx], [0, f, cy], [0, 0, 1]].
        let (fs, sx, sy) = (
            src.camera.f as f32,
            src.camera.cx as f32,
            src.camera.cy as f32,
        );
        let mut a = [0.0f32; 9];
        for col in 0..3 {
            a[col] = fs * m[col] + sx * m[6 + col];
            a[3 + col] = fs * m[3 + col] + sy * m[6 + col];
            a[6 + col] = m[6 + col];
        }
        let b = [fs * t[0] + sx * t[2], fs * t[1] + sy * t[2], t[2]];
        PlaneWarp { a, b }
    }

    /// The homography of the plane whose row is `c`, row-major.
    #[inline]
    pub fn homography(&self, c: &PlaneRow) -> [f32; 9] {
        let (a, b, c) = (&self.a, &self.b, &c.0);
        std::array::from_fn(|k| a[k] - b[k / 3] * c[k % 3])
    }
}

/// The homography from reference pixels to source pixels induced by the plane `n·X + w = 0`
/// (reference camera frame): `H = K_s (R − t nᵀ / w) K_r⁻¹`, row-major.
#[inline]
pub fn homography(src: &SourceView<'_>, k_ref: &RefCamera, n: &[f32; 3], w: f32) -> [f32; 9] {
    PlaneWarp::new(src, k_ref).homography(&PlaneRow::new(k_ref, n, w))
}

/// 1 − NCC of the reference window at (u, v) (pixel centre) against the source through `h`,
/// in [0, 2]; [`WORST`] when the window leaves the front of the source, its centre leaves the
/// source or lands on an unusable pixel, or the source window has no texture. Source samples
/// beyond the border are clamped to it.
#[inline]
pub fn ncc_cost(
    shape: &WindowShape,
    window: &RefWindow,
    src: &SourceView<'_>,
    h: &[f32; 9],
    u: f32,
    v: f32,
) -> f32 {
    let z = h[6] * u + h[7] * v + h[8];
    if !(z > 1e-6) {
        return WORST;
    }
    let cu = (h[0] * u + h[1] * v + h[2]) / z;
    let cv = (h[3] * u + h[4] * v + h[5]) / z;
    let (sw, sh) = (src.grey.width as f32, src.grey.height as f32);
    if !(cu >= 0.0 && cv >= 0.0 && cu < sw && cv < sh && src.mask.at(cu as usize, cv as usize)) {
        return WORST;
    }
    // The window's corners in front of the source (a plane seen edge-on folds the window).
    let (lo, hi) = shape.extent;
    if [(lo, lo), (hi, lo), (lo, hi), (hi, hi)]
        .iter()
        .any(|&(dx, dy)| !(h[6] * (u + dx) + h[7] * (v + dy) + h[8] > 1e-6))
    {
        return WORST;
    }
    // Scratch arrays no larger than the window needs: zeroing them is part of every call.
    let m = if shape.len() <= SMALL_WINDOW {
        window_moments::<SMALL_WINDOW>(shape, window, src.grey, h, u, v)
    } else {
        window_moments::<MAX_WINDOW>(shape, window, src.grey, h, u, v)
    };
    // Most of the window must land inside the source.
    if !(m.weight >= MIN_INSIDE) {
        return WORST;
    }
    let inv = 1.0 / m.weight;
    let (mr, ms) = (m.r * inv, m.s * inv);
    let var_r = m.rr * inv - mr * mr;
    let var_s = m.ss * inv - ms * ms;
    if !(var_s > MIN_VARIANCE) || !(var_r > MIN_VARIANCE) {
        return WORST;
    }
    let ncc = (m.rs * inv - mr * ms) / (var_r * var_s).sqrt();
    (1.0 - ncc).clamp(0.0, WORST)
}

/// Least share of the reference window's weight that must fall inside the source image.
const MIN_INSIDE: f32 = 0.5;

/// Weighted sums over the window samples that fall inside the source image.
#[derive(Debug, Clone, Copy, Default)]
struct Moments {
    weight: f32,
    r: f32,
    rr: f32,
    s: f32,
    ss: f32,
    rs: f32,
}

/// Window capacity of the default options' windows (radius 5, step 2: 32 samples).
const SMALL_WINDOW: usize = 32;

/// The weighted sums of the reference and source samples, over the samples inside the source,
/// with scratch arrays of `CAP` samples (at least the window's padded length).
#[inline]
fn window_moments<const CAP: usize>(
    shape: &WindowShape,
    window: &RefWindow,
    grey: &Plane,
    h: &[f32; 9],
    u: f32,
    v: f32,
) -> Moments {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU supports AVX2 and FMA, checked just above.
        return unsafe { window_moments_avx2::<CAP>(shape, window, grey, h, u, v) };
    }
    window_moments_portable::<CAP>(shape, window, grey, h, u, v)
}

/// [`window_moments_portable`] with explicit AVX2: eight samples per step in registers, the
/// four bilinear corners fetched by gathers. The same operations in the same order (no fused
/// multiply–add), so the result is the portable kernel's bit for bit (a test checks it).
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
// Long function: the SIMD twin of `window_moments_portable`, step for step so that the bit-for-bit
// test can hold; its eight-lane accumulators live in registers across the whole window.
unsafe fn window_moments_avx2<const CAP: usize>(
    shape: &WindowShape,
    window: &RefWindow,
    grey: &Plane,
    h: &[f32; 9],
    u: f32,
    v: f32,
) -> Moments {
    use std::arch::x86_64::*;
    let n = shape.len();
    let (width, height) = (grey.width, grey.height);
    // The gathers read without bounds checks: every sample is clamped into the band of pixel
    // centres, so its four corners lie inside a plane of at least 2 × 2 whose data is complete.
    // Anything else (never built by this crate) takes the checked path.
    let gatherable = width >= 2
        && height >= 2
        && width * height <= grey.data.len()
        && width * height < i32::MAX as usize
        && n % LANES == 0
        && n <= CAP
        && window.weight.len() >= n
        && window.value.len() >= n
        && shape.dy.len() >= n;
    if !gatherable {
        return window_moments_portable::<CAP>(shape, window, grey, h, u, v);
    }
    let splat = |x: f32| _mm256_set1_ps(x);
    // Each splat by hand: `h.map(splat)` compiled to a call outside this function's features.
    let (h0, h1, h2) = (splat(h[0]), splat(h[1]), splat(h[2]));
    let (h3, h4, h5) = (splat(h[3]), splat(h[4]), splat(h[5]));
    let (h6, h7, h8) = (splat(h[6]), splat(h[7]), splat(h[8]));
    let (uu, vv) = (splat(u), splat(v));
    let (zero, one, half) = (splat(0.0), splat(1.0), splat(0.5));
    let xmax = splat((width - 1) as f32 - 1e-3);
    let ymax = splat((height - 1) as f32 - 1e-3);
    let row = _mm256_set1_epi32(width as i32);
    let data = grey.data.as_ptr();
    // Pass 1: the interpolated source value and the effective weight of every sample.
    let mut value = [0.0f32; CAP];
    let mut weight = [0.0f32; CAP];
    for k0 in (0..n).step_by(LANES) {
        // SAFETY (all loads, gathers and stores of this loop): k0 + LANES ≤ n ≤ CAP and n ≤
        // the lengths of the shape's and window's vectors, checked above; the gathers are
        // proven in bounds where they are.
        unsafe {
            let x = _mm256_add_ps(uu, _mm256_loadu_ps(shape.dx.as_ptr().add(k0)));
            let y = _mm256_add_ps(vv, _mm256_loadu_ps(shape.dy.as_ptr().add(k0)));
            let den = _mm256_add_ps(
                _mm256_add_ps(_mm256_mul_ps(h6, x), _mm256_mul_ps(h7, y)),
                h8,
            );
            let iz = _mm256_div_ps(one, den);
            let nx = _mm256_add_ps(
                _mm256_add_ps(_mm256_mul_ps(h0, x), _mm256_mul_ps(h1, y)),
                h2,
            );
            let ny = _mm256_add_ps(
                _mm256_add_ps(_mm256_mul_ps(h3, x), _mm256_mul_ps(h4, y)),
                h5,
            );
            let sx = _mm256_sub_ps(_mm256_mul_ps(nx, iz), half);
            let sy = _mm256_sub_ps(_mm256_mul_ps(ny, iz), half);
            // A NaN position (only from a homography of overflowing entries) would be clamped
            // differently by min/max than by f32::clamp: leave such windows to the portable kernel.
            if _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_UNORD_Q>(sx, sy)) != 0 {
                return window_moments_portable::<CAP>(shape, window, grey, h, u, v);
            }
            // f32::clamp, for numbers.
            let cx = _mm256_min_ps(_mm256_max_ps(sx, zero), xmax);
            let cy = _mm256_min_ps(_mm256_max_ps(sy, zero), ymax);
            let inside = _mm256_and_ps(
                _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_EQ_OQ>(cx, sx),
                    _mm256_cmp_ps::<_CMP_EQ_OQ>(cy, sy),
                ),
                one,
            );
            let i = _mm256_cvttps_epi32(cx);
            let j = _mm256_cvttps_epi32(cy);
            let fx = _mm256_sub_ps(cx, _mm256_cvtepi32_ps(i));
            let fy = _mm256_sub_ps(cy, _mm256_cvtepi32_ps(j));
            let at = _mm256_add_epi32(_mm256_mullo_epi32(j, row), i);
            let mut index = [0i32; LANES];
            _mm256_storeu_si256(index.as_mut_ptr() as *mut __m256i, at);
            // Each corner pair (left, right) is one unaligned 8-byte load, put in lanes
            // (0 1 4 5 | 2 3 6 7) so that unpacking the pairs gives the samples in order. Plain
            // loads, not gathers: on the CPUs measured (AMD Zen 3) a gather of four pairs cost
            // more than the four loads and inserts.
            // SAFETY: 0 ≤ i ≤ width − 2 and 0 ≤ j ≤ height − 2 (positions clamped below
            // width − 1 and height − 1), so both corners of a pair, and of the pair below it,
            // lie below width × height ≤ len.
            let pairs = |below: usize| {
                let pair =
                    |l: usize| (data.add(index[l] as usize + below) as *const i64).read_unaligned();
                let first = _mm256_setr_epi64x(pair(0), pair(1), pair(4), pair(5));
                let second = _mm256_setr_epi64x(pair(2), pair(3), pair(6), pair(7));
                let (first, second) = (_mm256_castsi256_ps(first), _mm256_castsi256_ps(second));
                (
                    _mm256_shuffle_ps::<0b10_00_10_00>(first, second),
                    _mm256_shuffle_ps::<0b11_01_11_01>(first, second),
                )
            };
            let (a, b) = pairs(0);
            let (c, d) = pairs(width);
            let top = _mm256_add_ps(a, _mm256_mul_ps(_mm256_sub_ps(b, a), fx));
            let bottom = _mm256_add_ps(c, _mm256_mul_ps(_mm256_sub_ps(d, c), fx));
            let val = _mm256_add_ps(top, _mm256_mul_ps(_mm256_sub_ps(bottom, top), fy));
            _mm256_storeu_ps(value.as_mut_ptr().add(k0), val);
            let w = _mm256_mul_ps(_mm256_loadu_ps(window.weight.as_ptr().add(k0)), inside);
            _mm256_storeu_ps(weight.as_mut_ptr().add(k0), w);
        }
    }
    // Pass 2: the sums, relative to one sample's value as in the portable kernel.
    let offset = splat(value[shape.samples / 2]);
    let mut acc = [zero; 6];
    for k0 in (0..n).step_by(LANES) {
        // SAFETY: as in pass 1.
        unsafe {
            let w = _mm256_loadu_ps(weight.as_ptr().add(k0));
            let r = _mm256_loadu_ps(window.value.as_ptr().add(k0));
            let s = _mm256_sub_ps(_mm256_loadu_ps(value.as_ptr().add(k0)), offset);
            let wr = _mm256_mul_ps(w, r);
            let ws = _mm256_mul_ps(w, s);
            acc[0] = _mm256_add_ps(acc[0], w);
            acc[1] = _mm256_add_ps(acc[1], wr);
            acc[2] = _mm256_add_ps(acc[2], _mm256_mul_ps(wr, r));
            acc[3] = _mm256_add_ps(acc[3], ws);
            acc[4] = _mm256_add_ps(acc[4], _mm256_mul_ps(ws, s));
            acc[5] = _mm256_add_ps(acc[5], _mm256_mul_ps(wr, s));
        }
    }
    Moments {
        weight: sum_lanes_avx2(acc[0]),
        r: sum_lanes_avx2(acc[1]),
        rr: sum_lanes_avx2(acc[2]),
        s: sum_lanes_avx2(acc[3]),
        ss: sum_lanes_avx2(acc[4]),
        rs: sum_lanes_avx2(acc[5]),
    }
}

/// The kernel, written in stages the compiler vectorises (positions, bilinear weights,
/// accumulation in [`LANES`] independent lanes) around the scalar gather of the four corners.
/// Floating-point operations are never contracted or reordered, so every instruction set gives
/// the same result. Never inlined: its scratch arrays (5 KB at the largest window) would give
/// every caller a stack frame that is probed page by page on each call, and on x86-64 it is
/// only the fallback of the AVX2 kernel.
#[inline(never)]
fn window_moments_portable<const CAP: usize>(
    shape: &WindowShape,
    window: &RefWindow,
    grey: &Plane,
    h: &[f32; 9],
    u: f32,
    v: f32,
) -> Moments {
    let n = shape.len();
    let (dx, dy) = (&shape.dx[..n], &shape.dy[..n]);
    let mut px = [0.0f32; CAP];
    let mut py = [0.0f32; CAP];
    let mut inside = [0.0f32; CAP];
    // Continuous positions relative to the band of pixel centres; samples beyond it are
    // clamped for the gather and weighted 0.
    let xmax = (grey.width - 1) as f32 - 1e-3;
    let ymax = (grey.height - 1) as f32 - 1e-3;
    for k in 0..n {
        let x = u + dx[k];
        let y = v + dy[k];
        let iz = 1.0 / (h[6] * x + h[7] * y + h[8]);
        let sx = (h[0] * x + h[1] * y + h[2]) * iz - 0.5;
        let sy = (h[3] * x + h[4] * y + h[5]) * iz - 0.5;
        let cx = sx.clamp(0.0, xmax);
        let cy = sy.clamp(0.0, ymax);
        inside[k] = if cx == sx && cy == sy { 1.0 } else { 0.0 };
        px[k] = cx;
        py[k] = cy;
    }
    // Integer corners and fractions (vectorised), then the scalar gather of the four corners,
    // then the interpolation (vectorised).
    let width = grey.width;
    let mut index = [0u32; CAP];
    for k in 0..n {
        let (i, j) = (px[k] as u32, py[k] as u32);
        px[k] -= i as f32;
        py[k] -= j as f32;
        index[k] = j * width as u32 + i;
    }
    let data = &grey.data;
    let mut corners = [[0.0f32; 4]; CAP];
    for k in 0..n {
        let at = index[k] as usize;
        let top = &data[at..at + 2];
        let bottom = &data[at + width..at + width + 2];
        corners[k] = [top[0], top[1], bottom[0], bottom[1]];
    }
    let mut value = [0.0f32; CAP];
    for k in 0..n {
        let [a, b, c, d] = corners[k];
        let top = a + (b - a) * px[k];
        let bottom = c + (d - c) * px[k];
        value[k] = top + (bottom - top) * py[k];
    }
    // Relative to one sample, which keeps the variance accurate in f32.
    let offset = value[shape.samples / 2];
    let mut acc = [[0.0f32; LANES]; 6];
    for k0 in (0..n).step_by(LANES) {
        for l in 0..LANES {
            let k = k0 + l;
            let w = window.weight[k] * inside[k];
            let r = window.value[k];
            let s = value[k] - offset;
            let wr = w * r;
            let ws = w * s;
            acc[0][l] += w;
            acc[1][l] += wr;
            acc[2][l] += wr * r;
            acc[3][l] += ws;
            acc[4][l] += ws * s;
            acc[5][l] += wr * s;
        }
    }
    Moments {
        weight: sum_lanes(&acc[0]),
        r: sum_lanes(&acc[1]),
        rr: sum_lanes(&acc[2]),
        s: sum_lanes(&acc[3]),
        ss: sum_lanes(&acc[4]),
        rs: sum_lanes(&acc[5]),
    }
}

/// [`sum_lanes`] of an AVX2 accumulator: the same order, so the same bits as the portable sums.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn sum_lanes_avx2(a: std::arch::x86_64::__m256) -> f32 {
    let mut lanes = [0.0f32; LANES];
    // SAFETY: `lanes` holds LANES = 8 floats.
    unsafe { std::arch::x86_64::_mm256_storeu_ps(lanes.as_mut_ptr(), a) };
    sum_lanes(&lanes)
}

/// The lanes of an accumulator added in lane order: both kernels end with it, so their sums
/// round alike.
#[inline(always)]
fn sum_lanes(lanes: &[f32; LANES]) -> f32 {
    lanes.iter().fold(0.0f32, |t, &x| t + x)
}

/// The geometric-consistency term (ACMM): the reference pixel (u, v) at depth `depth` is
/// projected into the source, lifted with the source's own depth there, and projected back;
/// the distance to (u, v) in pixels, at most `max_px` (also when the source has no depth there).
#[inline]
pub fn geometric_cost(
    src: &SourceView<'_>,
    k_ref: &RefCamera,
    u: f32,
    v: f32,
    depth: f32,
    max_px: f32,
) -> f32 {
    let Some((map, cam)) = src.depth else {
        return 0.0;
    };
    let ray = k_ref.ray(u, v);
    let x = [ray[0] * depth, ray[1] * depth, depth];
    let r = &src.r;
    let t = &src.t;
    let xs = [
        r[0] * x[0] + r[1] * x[1] + r[2] * x[2] + t[0],
        r[3] * x[0] + r[4] * x[1] + r[5] * x[2] + t[1],
        r[6] * x[0] + r[7] * x[1] + r[8] * x[2] + t[2],
    ];
    if !(xs[2] > 0.0) {
        return max_px;
    }
    let (f, cx, cy) = (cam.f as f32, cam.cx as f32, cam.cy as f32);
    let us = cx + f * xs[0] / xs[2];
    let vs = cy + f * xs[1] / xs[2];
    if !(us >= 0.0 && vs >= 0.0 && us < cam.width as f32 && vs < cam.height as f32) {
        return max_px;
    }
    let d = map[vs as usize * cam.width + us as usize];
    if !(d > 0.0) {
        return max_px;
    }
    // Lift (us, vs) with the source's depth, back to the reference frame: X = Rᵀ (Xs − t).
    let ys = [(us - cx) / f * d - t[0], (vs - cy) / f * d - t[1], d - t[2]];
    let y = [
        r[0] * ys[0] + r[3] * ys[1] + r[6] * ys[2],
        r[1] * ys[0] + r[4] * ys[1] + r[7] * ys[2],
        r[2] * ys[0] + r[5] * ys[1] + r[8] * ys[2],
    ];
    if !(y[2] > 0.0) {
        return max_px;
    }
    let du = k_ref.cx + k_ref.f * y[0] / y[2] - u;
    let dv = k_ref.cy + k_ref.f * y[1] / y[2] - v;
    (du * du + dv * dv).sqrt().min(max_px)
}

/// Depth at the ray `ray` (z = 1) of the plane `n·X + w = 0`; non-positive when the plane does
/// not face the ray.
#[inline]
pub fn plane_depth(n: &[f32; 3], w: f32, ray: &[f32; 3]) -> f32 {
    let denom = dot(n, ray);
    if denom.abs() < 1e-8 {
        return -1.0;
    }
    -w / denom
}

/// Offset `w` of the plane through the point at `depth` on `ray` with normal `n`.
#[inline]
pub fn plane_offset(n: &[f32; 3], depth: f32, ray: &[f32; 3]) -> f32 {
    -(dot(n, ray) * depth)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(w: usize, h: usize, f: f64) -> WorkingCamera {
        WorkingCamera {
            width: w,
            height: h,
            f,
            cx: 0.5 * w as f64 + 1.5,
            cy: 0.5 * h as f64 - 2.0,
        }
    }

    /// The homography of a plane maps every reference pixel to the projection of the plane's
    /// point on its ray.
    #[test]
    fn homography_maps_plane_points() {
        let kr = camera(100, 80, 90.0);
        let ks = camera(120, 90, 110.0);
        // src_from_ref: a rotation of 0.1 rad about y and a shift.
        let (c, s) = (0.1f32.cos(), 0.1f32.sin());
        let r = [c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c];
        let t = [-0.5, 0.1, 0.05];
        let grey = Plane::filled(120, 90, 0.0);
        let mask = Mask::all(120, 90);
        let src = SourceView {
            grey: &grey,
            mask: &mask,
            camera: ks,
            r,
            t,
            depth: None,
        };
        let k_ref = RefCamera::of(&kr);
        let n = {
            let v = [0.2f32, -0.1, -1.0];
            let l = dot(&v, &v).sqrt();
            [v[0] / l, v[1] / l, v[2] / l]
        };
        let ray0 = k_ref.ray(50.0, 40.0);
        let w = plane_offset(&n, 10.0, &ray0);
        let h = homography(&src, &k_ref, &n, w);
        for (u, v) in [(10.5f32, 12.5f32), (70.5, 60.5), (50.0, 40.0)] {
            let ray = k_ref.ray(u, v);
            let d = plane_depth(&n, w, &ray);
            let x = [ray[0] * d, ray[1] * d, d];
            let xs = [
                r[0] * x[0] + r[1] * x[1] + r[2] * x[2] + t[0],
                r[3] * x[0] + r[4] * x[1] + r[5] * x[2] + t[1],
                r[6] * x[0] + r[7] * x[1] + r[8] * x[2] + t[2],
            ];
            let expected = (
                ks.cx as f32 + ks.f as f32 * xs[0] / xs[2],
                ks.cy as f32 + ks.f as f32 * xs[1] / xs[2],
            );
            let z = h[6] * u + h[7] * v + h[8];
            let got = (
                (h[0] * u + h[1] * v + h[2]) / z,
                (h[3] * u + h[4] * v + h[5]) / z,
            );
            assert!((got.0 - expected.0).abs() < 1e-3, "{got:?} {expected:?}");
            assert!((got.1 - expected.1).abs() < 1e-3, "{got:?} {expected:?}");
        }
    }

    #[test]
    fn ncc_is_zero_cost_for_identical_views_and_worst_without_texture() {
        let k = camera(60, 50, 60.0);
        let mut grey = Plane::filled(60, 50, 0.0);
        for j in 0..50 {
            for i in 0..60 {
                grey.data[j * 60 + i] =
                    0.5 + 0.2 * ((i as f32 * 0.7).sin() * (j as f32 * 0.45).cos());
            }
        }
        let mask = Mask::all(60, 50);
        let identity = SourceView {
            grey: &grey,
            mask: &mask,
            camera: k,
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            t: [0.0, 0.0, 0.0],
            depth: None,
        };
        let shape = WindowShape::new(4, 2, 4.0, 0.1).unwrap();
        let mut window = RefWindow::new(&shape);
        assert!(window.fill(&shape, &grey, 30, 25));
        let k_ref = RefCamera::of(&k);
        let n = [0.0, 0.0, -1.0];
        let h = homography(&identity, &k_ref, &n, 5.0);
        let cost = ncc_cost(&shape, &window, &identity, &h, 30.5, 25.5);
        assert!(cost < 1e-4, "{cost}");
        let flat = Plane::filled(60, 50, 0.3);
        assert!(!window.fill(&shape, &flat, 30, 25));
        let flat_src = SourceView {
            grey: &flat,
            ..identity
        };
        assert!(window.fill(&shape, &grey, 30, 25));
        assert_eq!(ncc_cost(&shape, &window, &flat_src, &h, 30.5, 25.5), WORST);
    }

    /// The AVX2 kernel is the portable one bit for bit: random textures, windows of both
    /// capacities, homographies that tilt, scale and shift the window, pixels up to and beyond
    /// the borders (clamped samples, windows partly outside the source).
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_avx2_kernel_gives_the_portable_kernels_bits() {
        use proptest::prelude::*;
        if !(std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")) {
            eprintln!(
                "skipped: this CPU has no AVX2 and FMA, so the portable kernel is the only one"
            );
            return;
        }
        let bits = |m: Moments| [m.weight, m.r, m.rr, m.s, m.ss, m.rs].map(f32::to_bits);
        let config = ProptestConfig {
            cases: 256,
            ..ProptestConfig::default()
        };
        proptest!(config, |(
            seed in 0u64..1_000_000,
            (width, height) in (2usize..90, 2usize..70),
            step in 1usize..=2,
            (u, v) in (-8.0f32..100.0, -8.0f32..80.0),
            scale in 0.5f32..2.0,
            (skew, tilt_x, tilt_y) in (-0.3f32..0.3, -0.004f32..0.004, -0.004f32..0.004),
            (shift_x, shift_y) in (-20.0f32..20.0, -20.0f32..20.0),
        )| {
            let mut rng = timesift_core::SeededRng::new(seed);
            let mut grey = Plane::filled(width, height, 0.0);
            for x in &mut grey.data {
                *x = rng.uniform() as f32;
            }
            let shape = WindowShape::new(5, step, 5.0, 0.1).expect("window");
            let mut window = RefWindow::new(&shape);
            let (i, j) = (u.clamp(0.0, (width - 1) as f32), v.clamp(0.0, (height - 1) as f32));
            window.fill(&shape, &grey, i as usize, j as usize);
            let h = [scale, skew, shift_x, -skew, scale, shift_y, tilt_x, tilt_y, 1.0];
            let portable = if shape.len() <= SMALL_WINDOW {
                window_moments_portable::<SMALL_WINDOW>(&shape, &window, &grey, &h, u, v)
            } else {
                window_moments_portable::<MAX_WINDOW>(&shape, &window, &grey, &h, u, v)
            };
            // SAFETY: AVX2 and FMA were detected above.
            let avx2 = unsafe {
                if shape.len() <= SMALL_WINDOW {
                    window_moments_avx2::<SMALL_WINDOW>(&shape, &window, &grey, &h, u, v)
                } else {
                    window_moments_avx2::<MAX_WINDOW>(&shape, &window, &grey, &h, u, v)
                }
            };
            prop_assert_eq!(bits(avx2), bits(portable));
        });
    }

    /// The AVX2 fill of the reference window is the portable one bit for bit: random
    /// textures and σ, windows of both steps and radii, pixels at and near the borders.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_avx2_window_fill_gives_the_portable_fills_bits() {
        use proptest::prelude::*;
        if !std::is_x86_feature_detected!("avx2") {
            eprintln!("skipped: this CPU has no AVX2, so the portable fill is the only one");
            return;
        }
        let config = ProptestConfig {
            cases: 256,
            ..ProptestConfig::default()
        };
        proptest!(config, |(
            seed in 0u64..1_000_000,
            (width, height) in (1usize..40, 1usize..30),
            (radius, step) in (1usize..=7, 1usize..=2),
            sigma_color in 0.01f32..0.3,
            (fx, fy) in (0.0f32..1.0, 0.0f32..1.0),
        )| {
            let mut rng = timesift_core::SeededRng::new(seed);
            let mut grey = Plane::filled(width, height, 0.0);
            for x in &mut grey.data {
                *x = rng.uniform() as f32;
            }
            let Some(shape) = WindowShape::new(radius, step.min(radius), radius as f32, sigma_color)
            else {
                return Ok(());
            };
            let (i, j) = ((fx * width as f32) as usize, (fy * height as f32) as usize);
            let (i, j) = (i.min(width - 1), j.min(height - 1));
            let mut portable = RefWindow::new(&shape);
            let textured = portable.fill_portable(&shape, &grey, i, j);
            let mut avx2 = RefWindow::new(&shape);
            // SAFETY: AVX2 was detected above.
            let textured_avx2 = unsafe { avx2.fill_avx2(&shape, &grey, i, j) };
            prop_assert_eq!(textured, textured_avx2);
            prop_assert_eq!(portable.variance.to_bits(), avx2.variance.to_bits());
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            prop_assert_eq!(bits(&portable.weight), bits(&avx2.weight));
            prop_assert_eq!(bits(&portable.value), bits(&avx2.value));
        });
    }
}
