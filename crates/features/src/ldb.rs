//! The LDB binary descriptor (Yang & Cheng 2012, "Local Difference Binary"): the oriented patch
//! is cut into 2×2, 3×3 and 4×4 grids; for every pair of cells of a grid, three bits compare their
//! mean intensity, mean x-gradient and mean y-gradient. 6 + 36 + 120 = 162 pairs × 3 = 486 bits,
//! stored in 61 bytes (the last two bits are zero) and compared by Hamming distance.
//!
//! Comparisons of means are invariant to any brightness change a·I + b with a > 0, and the grids
//! see the patch at three granularities, which makes the bits more distinctive than ORB's single
//! pixel pairs at the same cost.

use crate::extract::{Describer, LocalKeypoint};
use crate::image::Plane;

/// Samples per side of the resampled patch (divisible by 2, 3 and 4, with even cells).
const PATCH: usize = 24;
/// Side of the patch in units of the keypoint's σ: the footprint of the SIFT descriptor.
const PATCH_SIGMAS: f32 = 12.0;
/// Grids whose cell pairs are compared.
const GRIDS: [usize; 3] = [2, 3, 4];
/// Descriptor length in bits.
pub const LDB_BITS: usize = 3 * (6 + 36 + 120);
/// Descriptor length in bytes.
pub const LDB_BYTES: usize = LDB_BITS.div_ceil(8);

pub(crate) struct LdbDescriber;

impl Describer for LdbDescriber {
    type Elem = u8;

    fn width(&self) -> usize {
        LDB_BYTES
    }

    fn support(&self) -> f64 {
        (PATCH_SIGMAS * 0.5 * std::f32::consts::SQRT_2) as f64
    }

    fn describe(&self, layer: &Plane, kp: &LocalKeypoint, out: &mut [u8]) {
        let step = (PATCH_SIGMAS * kp.sigma / PATCH as f32) as f64;
        let (sin, cos) = (kp.angle as f64).sin_cos();
        // Integral image of the resampled, rotated patch: sums over any cell in four reads.
        let mut integral = [[0.0f32; PATCH + 1]; PATCH + 1];
        for v in 0..PATCH {
            let b = (v as f64 + 0.5 - PATCH as f64 / 2.0) * step;
            let mut row_sum = 0.0;
            for u in 0..PATCH {
                let a = (u as f64 + 0.5 - PATCH as f64 / 2.0) * step;
                let x = kp.x + cos * a - sin * b;
                let y = kp.y + sin * a + cos * b;
                row_sum += layer.bilinear(x, y);
                integral[v + 1][u + 1] = integral[v][u + 1] + row_sum;
            }
        }
        let sum = |x0: usize, y0: usize, w: usize, h: usize| {
            integral[y0 + h][x0 + w] - integral[y0][x0 + w] - integral[y0 + h][x0]
                + integral[y0][x0]
        };
        out.fill(0);
        let mut bit = 0;
        let mut cells = [[0.0f32; 3]; 16];
        for grid in GRIDS {
            let side = PATCH / grid;
            let half = side / 2;
            for cy in 0..grid {
                for cx in 0..grid {
                    let (x0, y0) = (cx * side, cy * side);
                    cells[cy * grid + cx] = [
                        sum(x0, y0, side, side),
                        sum(x0 + half, y0, half, side) - sum(x0, y0, half, side),
                        sum(x0, y0 + half, side, half) - sum(x0, y0, side, half),
                    ];
                }
            }
            let n = grid * grid;
            for i in 0..n {
                for j in i + 1..n {
                    for k in 0..3 {
                        if cells[i][k] > cells[j][k] {
                            out[bit / 8] |= 1 << (bit % 8);
                        }
                        bit += 1;
                    }
                }
            }
        }
        debug_assert_eq!(bit, LDB_BITS);
    }
}

/// Hamming distance between two binary descriptors.
pub fn hamming(a: &[u8], b: &[u8]) -> u32 {
    let mut distance = 0;
    let (chunks_a, rest_a) = a.split_at(a.len() / 8 * 8);
    let (chunks_b, rest_b) = b.split_at(b.len() / 8 * 8);
    for (x, y) in chunks_a.chunks_exact(8).zip(chunks_b.chunks_exact(8)) {
        let x = u64::from_le_bytes(x.try_into().unwrap_or([0; 8]));
        let y = u64::from_le_bytes(y.try_into().unwrap_or([0; 8]));
        distance += (x ^ y).count_ones();
    }
    for (x, y) in rest_a.iter().zip(rest_b) {
        distance += (x ^ y).count_ones();
    }
    distance
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_and_hamming() {
        assert_eq!(LDB_BITS, 486);
        assert_eq!(LDB_BYTES, 61);
        let a = [0xffu8; 61];
        let mut b = [0xffu8; 61];
        assert_eq!(hamming(&a, &b), 0);
        b[0] = 0;
        b[60] = 0x0f;
        assert_eq!(hamming(&a, &b), 12);
    }
}
