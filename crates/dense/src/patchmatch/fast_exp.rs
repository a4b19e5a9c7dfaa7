//! `exp` of non-positive arguments, for the bilateral weights and the view likelihoods of the
//! innermost loops. The C library's `expf` is a call the compiler cannot vectorise; this is
//! branch-free arithmetic it can, and it gives the same bits on every instruction set (Rust
//! never contracts `a * b + c` into a fused multiply–add), so results do not depend on the CPU.

/// Below this `exp` is under f32's normal range: the weight is 0.
const FLOOR: f32 = -87.0;
/// 1.5 × 2^23: adding and subtracting it rounds an f32 of magnitude below 2^22 to the
/// nearest integer.
const ROUND: f32 = 12_582_912.0;
/// ln 2 in two parts: n × LN2_HI is exact for |n| < 2^9.
const LN2_HI: f32 = 0.693_359_4;
const LN2_LO: f32 = -2.121_944_4e-4;
/// The Taylor coefficients of `e^r`, highest degree first.
const TAYLOR: [f32; 8] = [
    1.0 / 5040.0,
    1.0 / 720.0,
    1.0 / 120.0,
    1.0 / 24.0,
    1.0 / 6.0,
    0.5,
    1.0,
    1.0,
];
/// 2^23 + 127: `n` added to it has the biased exponent of 2^n as its low mantissa bits.
const BIAS: f32 = 8_388_608.0 + 127.0;

/// `exp(x)` for `x ≤ 0`, within 2.5e-7 relative error of the exact value; 0 below −87 and for
/// NaN. Cody–Waite reduction `x = n ln 2 + r`, |r| ≤ ln 2 / 2, then `e^r` by its Taylor
/// polynomial of degree 7 and `2^n` built from its exponent bits.
#[inline(always)]
pub fn exp_neg(x: f32) -> f32 {
    let clamped = x.clamp(FLOOR, 0.0);
    let n = (clamped * std::f32::consts::LOG2_E + ROUND) - ROUND;
    let r = (clamped - n * LN2_HI) - n * LN2_LO;
    let mut p = TAYLOR[0];
    for &c in &TAYLOR[1..] {
        p = p * r + c;
    }
    let scale = f32::from_bits(((n + BIAS).to_bits() & 0x007F_FFFF) << 23);
    if x >= FLOOR { p * scale } else { 0.0 }
}

/// [`exp_neg`] of eight lanes, step for step (the same bits per lane).
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
pub unsafe fn exp_neg_avx2(x: std::arch::x86_64::__m256) -> std::arch::x86_64::__m256 {
    use std::arch::x86_64::*;
    let splat = |v: f32| _mm256_set1_ps(v);
    // max then min is f32::clamp for numbers; a NaN lane is zeroed by the last step either way.
    let clamped = _mm256_min_ps(_mm256_max_ps(x, splat(FLOOR)), splat(0.0));
    let n = _mm256_sub_ps(
        _mm256_add_ps(
            _mm256_mul_ps(clamped, splat(std::f32::consts::LOG2_E)),
            splat(ROUND),
        ),
        splat(ROUND),
    );
    let r = _mm256_sub_ps(
        _mm256_sub_ps(clamped, _mm256_mul_ps(n, splat(LN2_HI))),
        _mm256_mul_ps(n, splat(LN2_LO)),
    );
    let mut p = splat(TAYLOR[0]);
    for &c in &TAYLOR[1..] {
        p = _mm256_add_ps(_mm256_mul_ps(p, r), splat(c));
    }
    let biased = _mm256_and_si256(
        _mm256_castps_si256(_mm256_add_ps(n, splat(BIAS))),
        _mm256_set1_epi32(0x007F_FFFF),
    );
    let scale = _mm256_castsi256_ps(_mm256_slli_epi32::<23>(biased));
    let keep = _mm256_cmp_ps::<_CMP_GE_OQ>(x, splat(FLOOR));
    _mm256_and_ps(_mm256_mul_ps(p, scale), keep)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_of_non_positive_arguments_is_within_its_bound() {
        assert_eq!(exp_neg(0.0), 1.0);
        let mut worst = 0.0f64;
        for k in 0..=870_000 {
            let x = -(k as f32) * 1e-4;
            let exact = (x as f64).exp();
            let err = ((exp_neg(x) as f64 - exact) / exact).abs();
            worst = worst.max(err);
        }
        assert!(worst < 2.5e-7, "worst relative error {worst:e}");
        // Increasing, as the weights must be.
        let mut last = 0.0;
        for k in (0..=87_000).rev() {
            let y = exp_neg(-(k as f32) * 1e-3);
            assert!(y >= last, "not increasing at {}", -(k as f32) * 1e-3);
            last = y;
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_avx2_exponential_gives_the_scalar_ones_bits() {
        use std::arch::x86_64::*;
        if !std::is_x86_feature_detected!("avx2") {
            eprintln!("skipped: this CPU has no AVX2");
            return;
        }
        let mut x: Vec<f32> = (0..=8_800).map(|k| -(k as f32) * 0.01).collect();
        x.extend([
            f32::NAN,
            f32::NEG_INFINITY,
            -1e30,
            -87.0,
            -86.999,
            0.0,
            -0.0,
        ]);
        x.resize(x.len().div_ceil(8) * 8, -3.0);
        for chunk in x.chunks_exact(8) {
            let mut out = [0.0f32; 8];
            // SAFETY: AVX2 checked above; `chunk` and `out` hold 8 floats.
            unsafe {
                let v = exp_neg_avx2(_mm256_loadu_ps(chunk.as_ptr()));
                _mm256_storeu_ps(out.as_mut_ptr(), v);
            }
            for (x, y) in chunk.iter().zip(out) {
                assert_eq!(y.to_bits(), exp_neg(*x).to_bits(), "at {x}");
            }
        }
    }

    #[test]
    fn below_the_normal_range_and_for_nan_the_weight_is_zero() {
        assert_eq!(exp_neg(-87.5), 0.0);
        assert_eq!(exp_neg(-1e30), 0.0);
        assert_eq!(exp_neg(f32::NEG_INFINITY), 0.0);
        assert_eq!(exp_neg(f32::NAN), 0.0);
    }
}
