//! A textured test image for examples and doctests, so that they show the API rather than
//! image synthesis.

/// A `width × height` grey image (row-major, values in [0, 1]) of 80 soft Gaussian blobs at
/// fixed pseudo-random places, the whole pattern shifted right by `shift_x` pixels: two calls
/// with different shifts are two views of one textured plane.
pub fn blobs(width: usize, height: usize, shift_x: f64) -> Vec<f32> {
    let blobs: Vec<(f64, f64, f64, f64)> = (0..80u64)
        .map(|k| {
            let h = k.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 11;
            let (a, b, c) = (h % 997, (h / 997) % 991, (h / 988_027) % 7);
            (
                a as f64 / 997.0 * width as f64,
                b as f64 / 991.0 * height as f64,
                1.5 + 0.5 * c as f64,
                if k % 2 == 0 { 0.45 } else { -0.45 },
            )
        })
        .collect();
    (0..width * height)
        .map(|p| {
            let (x, y) = ((p % width) as f64 + 0.5 - shift_x, (p / width) as f64 + 0.5);
            let v: f64 = blobs
                .iter()
                .map(|&(bx, by, s, amp)| {
                    amp * (-((x - bx).powi(2) + (y - by).powi(2)) / (2.0 * s * s)).exp()
                })
                .sum();
            (0.5 + v).clamp(0.0, 1.0) as f32
        })
        .collect()
}
