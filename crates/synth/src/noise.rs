//! Seeded gradient noise (Perlin's improved noise on a hashed lattice) and fractal sums of it
//! (fBm): detail at many scales for textures and terrain, identical for a given seed on every
//! machine.

/// Gradient noise in 3-D, values in about [−1, 1], zero at lattice points.
#[derive(Debug, Clone, PartialEq)]
pub struct Noise {
    perm: [u8; 512],
}

impl Noise {
    /// The noise of a seed (the lattice permutation shuffled by splitmix64).
    pub fn new(seed: u64) -> Noise {
        let mut p: [u8; 256] = std::array::from_fn(|i| i as u8);
        let mut state = seed;
        for i in (1..256).rev() {
            state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^= z >> 31;
            p.swap(i, (z % (i as u64 + 1)) as usize);
        }
        let mut perm = [0u8; 512];
        for i in 0..512 {
            perm[i] = p[i & 255];
        }
        Noise { perm }
    }

    /// Noise at a point.
    pub fn at(&self, x: f64, y: f64, z: f64) -> f64 {
        let (xf, yf, zf) = (x.floor(), y.floor(), z.floor());
        let (xi, yi, zi) = (
            (xf as i64 & 255) as usize,
            (yf as i64 & 255) as usize,
            (zf as i64 & 255) as usize,
        );
        let (x, y, z) = (x - xf, y - yf, z - zf);
        let fade = |t: f64| t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
        let (u, v, w) = (fade(x), fade(y), fade(z));
        let p = &self.perm;
        let a = p[xi] as usize + yi;
        let (aa, ab) = (p[a] as usize + zi, p[a + 1] as usize + zi);
        let b = p[xi + 1] as usize + yi;
        let (ba, bb) = (p[b] as usize + zi, p[b + 1] as usize + zi);
        let lerp = |t: f64, a: f64, b: f64| a + t * (b - a);
        lerp(
            w,
            lerp(
                v,
                lerp(u, grad(p[aa], x, y, z), grad(p[ba], x - 1.0, y, z)),
                lerp(
                    u,
                    grad(p[ab], x, y - 1.0, z),
                    grad(p[bb], x - 1.0, y - 1.0, z),
                ),
            ),
            lerp(
                v,
                lerp(
                    u,
                    grad(p[aa + 1], x, y, z - 1.0),
                    grad(p[ba + 1], x - 1.0, y, z - 1.0),
                ),
                lerp(
                    u,
                    grad(p[ab + 1], x, y - 1.0, z - 1.0),
                    grad(p[bb + 1], x - 1.0, y - 1.0, z - 1.0),
                ),
            ),
        )
    }

    /// 2-D gradient noise at a point (half the work of [`Self::at`]), for textures mapped onto a
    /// plane.
    pub fn at2(&self, x: f64, y: f64) -> f64 {
        let (xf, yf) = (x.floor(), y.floor());
        let (xi, yi) = ((xf as i64 & 255) as usize, (yf as i64 & 255) as usize);
        let (x, y) = (x - xf, y - yf);
        let fade = |t: f64| t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
        let (u, v) = (fade(x), fade(y));
        let p = &self.perm;
        let (a, b) = (p[xi] as usize + yi, p[xi + 1] as usize + yi);
        let lerp = |t: f64, a: f64, b: f64| a + t * (b - a);
        lerp(
            v,
            lerp(u, grad2(p[a], x, y), grad2(p[b], x - 1.0, y)),
            lerp(
                u,
                grad2(p[a + 1], x, y - 1.0),
                grad2(p[b + 1], x - 1.0, y - 1.0),
            ),
        )
    }

    /// [`Self::fbm`] of the 2-D noise.
    pub fn fbm2(&self, x: f64, y: f64, scale: f64, octaves: u32, gain: f64) -> f64 {
        let (mut sum, mut amplitude, mut norm, mut frequency) = (0.0, 1.0, 0.0, 1.0 / scale);
        for k in 0..octaves {
            let shift = 17.31 * k as f64;
            sum += amplitude * self.at2(x * frequency + shift, y * frequency - shift);
            norm += amplitude;
            amplitude *= gain;
            frequency *= 2.0;
        }
        if norm > 0.0 { sum / norm } else { 0.0 }
    }

    /// Fractal sum of `octaves` octaves: frequency doubles and amplitude is multiplied by `gain` at
    /// each; the base wavelength is `scale` (world units). Normalised so the amplitude sum is 1.
    pub fn fbm(&self, x: f64, y: f64, z: f64, scale: f64, octaves: u32, gain: f64) -> f64 {
        let (mut sum, mut amplitude, mut norm, mut frequency) = (0.0, 1.0, 0.0, 1.0 / scale);
        for k in 0..octaves {
            // Each octave is shifted so that lattice points of successive octaves do not coincide.
            let shift = 17.31 * k as f64;
            sum += amplitude
                * self.at(
                    x * frequency + shift,
                    y * frequency - shift,
                    z * frequency + 0.5 * shift,
                );
            norm += amplitude;
            amplitude *= gain;
            frequency *= 2.0;
        }
        if norm > 0.0 { sum / norm } else { 0.0 }
    }
}

/// Dot product with one of eight unit-ish gradient directions.
fn grad2(hash: u8, x: f64, y: f64) -> f64 {
    match hash & 7 {
        0 => x + y,
        1 => -x + y,
        2 => x - y,
        3 => -x - y,
        4 => x,
        5 => -x,
        6 => y,
        _ => -y,
    }
}

fn grad(hash: u8, x: f64, y: f64, z: f64) -> f64 {
    let h = hash & 15;
    let u = if h < 8 { x } else { y };
    let v = if h < 4 {
        y
    } else if h == 12 || h == 14 {
        x
    } else {
        z
    };
    (if h & 1 == 0 { u } else { -u }) + (if h & 2 == 0 { v } else { -v })
}

/// A deterministic number in [0, 1) from integers.
pub(crate) fn hash01(a: i64, b: i64, c: u64) -> f64 {
    let mut z = (a as u64)
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add((b as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F))
        .wrapping_add(c.wrapping_mul(0x1656_67B1_9E37_79F9));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

/// Sparse speckles on a plane: in each square cell of side `cell`, with probability 0.6, one
/// Gaussian spot at a random place, of random radius (0.12–0.32 cell), sign and amplitude
/// (0.5–1). Values roughly in [−1.5, 1.5]; deterministic in `seed`.
pub(crate) fn speckles2(x: f64, y: f64, cell: f64, seed: u64) -> f64 {
    let (ci, cj) = ((x / cell).floor() as i64, (y / cell).floor() as i64);
    let mut sum = 0.0;
    for i in ci - 1..=ci + 1 {
        for j in cj - 1..=cj + 1 {
            sum += spot(i, j, 0, cell, seed, |px, py, _| {
                (x - px).powi(2) + (y - py).powi(2)
            });
        }
    }
    sum
}

/// [`speckles2`] in space (cubic cells), for textures on meshes.
pub(crate) fn speckles3(x: f64, y: f64, z: f64, cell: f64, seed: u64) -> f64 {
    let (ci, cj, ck) = (
        (x / cell).floor() as i64,
        (y / cell).floor() as i64,
        (z / cell).floor() as i64,
    );
    let mut sum = 0.0;
    for i in ci - 1..=ci + 1 {
        for j in cj - 1..=cj + 1 {
            for k in ck - 1..=ck + 1 {
                sum += spot(i, j, k, cell, seed, |px, py, pz| {
                    (x - px).powi(2) + (y - py).powi(2) + (z - pz).powi(2)
                });
            }
        }
    }
    sum
}

/// The spot of cell (i, j, k) at squared distance `d2(centre)`.
#[inline]
fn spot(i: i64, j: i64, k: i64, cell: f64, seed: u64, d2: impl Fn(f64, f64, f64) -> f64) -> f64 {
    let key = seed ^ (k as u64).wrapping_mul(0xA24B_AED4_963E_E407);
    if hash01(i, j, key) >= 0.6 {
        return 0.0;
    }
    let centre = (
        (i as f64 + hash01(i, j, key ^ 1)) * cell,
        (j as f64 + hash01(i, j, key ^ 2)) * cell,
        (k as f64 + hash01(i, j, key ^ 3)) * cell,
    );
    let radius = cell * (0.12 + 0.2 * hash01(i, j, key ^ 4));
    let distance2 = d2(centre.0, centre.1, centre.2);
    if distance2 > 9.0 * radius * radius {
        return 0.0;
    }
    let sign = if hash01(i, j, key ^ 5) < 0.5 {
        -1.0
    } else {
        1.0
    };
    let amplitude = 0.5 + 0.5 * hash01(i, j, key ^ 6);
    sign * amplitude * (-distance2 / (2.0 * radius * radius)).exp()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_is_seeded_smooth_and_bounded() {
        let a = Noise::new(7);
        let b = Noise::new(7);
        let c = Noise::new(8);
        let (mut same, mut differs, mut max_abs, mut max_step) = (true, false, 0.0f64, 0.0f64);
        for i in 0..2000 {
            let (x, y, z) = (
                i as f64 * 0.173,
                i as f64 * 0.0917 - 3.0,
                0.31 * (i % 7) as f64,
            );
            let v = a.at(x, y, z);
            same &= v == b.at(x, y, z);
            differs |= v != c.at(x, y, z);
            max_abs = max_abs.max(v.abs());
            // Lipschitz-like smoothness: a 1e-3 step changes the value by O(1e-3).
            max_step = max_step.max((a.at(x + 1e-3, y, z) - v).abs());
        }
        assert!(same && differs);
        assert!(max_abs <= 1.5 && max_abs > 0.3, "{max_abs}");
        assert!(max_step < 5e-3, "{max_step}");
        assert_eq!(a.at(3.0, 4.0, 5.0), 0.0, "zero on the lattice");
        let f = a.fbm(12.3, 4.5, 0.0, 10.0, 6, 0.5);
        assert!(f.abs() <= 1.5);
    }
}
