//! Camera and scan effects applied to a rendered image: exposure, vignetting, sensor noise and 8-bit
//! quantisation for digital cameras; film grain, dust and scratches for scanned archival photos.
//! Seeded, so an image is the same on every run.

use timesift_core::SeededRng;

use crate::render::RgbImage;

/// What the sensor records.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Channels {
    /// Red, green and blue (digital cameras).
    Rgb,
    /// Luminance only (panchromatic film).
    Grey,
}

impl Channels {
    /// Values per pixel.
    pub fn count(self) -> usize {
        match self {
            Channels::Rgb => 3,
            Channels::Grey => 1,
        }
    }
}

/// Effects of one image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Effects {
    /// Multiplier of the rendered radiance before quantisation (1 = as rendered).
    pub exposure: f64,
    /// Relative darkening at the image corners (cos⁴-like falloff, 0 = none).
    pub vignetting: f64,
    /// Gaussian sensor noise, in 8-bit grey levels.
    pub noise_sigma: f64,
    /// Film-grain contrast (multiplicative noise on 2 × 2 pixel grains, 0 = none).
    pub grain: f64,
    /// Dust specks per megapixel.
    pub dust_per_mp: f64,
    /// Scratches (long thin lines) per image.
    pub scratches: u32,
    /// Seed of every random draw.
    pub seed: u64,
    /// What is recorded.
    pub channels: Channels,
}

impl Default for Effects {
    fn default() -> Self {
        Effects {
            exposure: 1.0,
            vignetting: 0.0,
            noise_sigma: 0.0,
            grain: 0.0,
            dust_per_mp: 0.0,
            scratches: 0,
            seed: 0,
            channels: Channels::Rgb,
        }
    }
}

/// The 8-bit image the effects give, channels interleaved (`effects.channels`).
pub fn apply(img: &RgbImage, effects: &Effects) -> Vec<u8> {
    let (w, h) = (img.width, img.height);
    let nc = effects.channels.count();
    let mut rng = SeededRng::new(effects.seed);
    let (cx, cy) = (0.5 * w as f64, 0.5 * h as f64);
    let r_max2 = cx * cx + cy * cy;
    let grains_x = w.div_ceil(2);
    let grain: Vec<f64> = (0..grains_x * h.div_ceil(2))
        .map(|_| 1.0 + effects.grain * rng.normal())
        .collect();
    let mut out = vec![0.0f64; w * h * nc];
    for (k, px) in img.data.iter().enumerate() {
        let (i, j) = (k % w, k / w);
        let (dx, dy) = (i as f64 + 0.5 - cx, j as f64 + 0.5 - cy);
        let falloff = 1.0 - effects.vignetting * (dx * dx + dy * dy) / r_max2;
        let gain = 255.0 * effects.exposure * falloff * grain[(j / 2) * grains_x + i / 2];
        match effects.channels {
            Channels::Rgb => {
                for c in 0..3 {
                    out[3 * k + c] = gain * px[c] as f64;
                }
            }
            Channels::Grey => {
                out[k] = gain * (0.299 * px[0] as f64 + 0.587 * px[1] as f64 + 0.114 * px[2] as f64)
            }
        }
    }
    if effects.noise_sigma > 0.0 {
        for v in &mut out {
            *v += effects.noise_sigma * rng.normal();
        }
    }
    let specks = (effects.dust_per_mp * (w * h) as f64 / 1e6).round() as usize;
    for _ in 0..specks {
        let (x, y) = (
            rng.uniform_range(0.0, w as f64),
            rng.uniform_range(0.0, h as f64),
        );
        let radius = rng.uniform_range(0.5, 2.5);
        let value = if rng.uniform() < 0.5 { 20.0 } else { 235.0 };
        stamp_disc(&mut out, w, h, nc, x, y, radius, value);
    }
    for _ in 0..effects.scratches {
        let (mut x, mut y) = (rng.uniform_range(0.0, w as f64), 0.0);
        let slope = rng.uniform_range(-0.15, 0.15);
        let value = if rng.uniform() < 0.7 { 230.0 } else { 30.0 };
        while y < h as f64 {
            stamp_disc(&mut out, w, h, nc, x, y, 0.6, value);
            x += slope;
            y += 0.5;
        }
    }
    out.iter()
        .map(|v| v.round().clamp(0.0, 255.0) as u8)
        .collect()
}

#[allow(clippy::too_many_arguments)]
fn stamp_disc(
    out: &mut [f64],
    w: usize,
    h: usize,
    nc: usize,
    x: f64,
    y: f64,
    radius: f64,
    value: f64,
) {
    let r = radius.ceil() as i64;
    for j in (y as i64 - r)..=(y as i64 + r) {
        for i in (x as i64 - r)..=(x as i64 + r) {
            if i < 0 || j < 0 || i >= w as i64 || j >= h as i64 {
                continue;
            }
            let (dx, dy) = (i as f64 + 0.5 - x, j as f64 + 0.5 - y);
            if dx * dx + dy * dy <= radius * radius {
                let k = j as usize * w + i as usize;
                out[nc * k..nc * (k + 1)].fill(value);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn effects_are_seeded_and_do_what_they_say() {
        let img = RgbImage {
            width: 200,
            height: 100,
            data: vec![[0.5; 3]; 20_000],
        };
        let plain = apply(&img, &Effects::default());
        assert!(plain.len() == 60_000 && plain.iter().all(|&v| v == 128));
        let dark = apply(
            &img,
            &Effects {
                exposure: 0.5,
                ..Default::default()
            },
        );
        assert!(dark.iter().all(|&v| v == 64));
        let vignette = apply(
            &img,
            &Effects {
                vignetting: 0.4,
                ..Default::default()
            },
        );
        assert!(vignette[0] < vignette[3 * (50 * 200 + 100)] && vignette[0] >= 75);
        let noisy = Effects {
            noise_sigma: 4.0,
            seed: 3,
            ..Default::default()
        };
        let (a, b) = (apply(&img, &noisy), apply(&img, &noisy));
        assert_eq!(a, b);
        let mean = a.iter().map(|&v| v as f64).sum::<f64>() / a.len() as f64;
        let sd =
            (a.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / a.len() as f64).sqrt();
        assert!(
            (mean - 127.5).abs() < 0.3 && (sd - 4.0).abs() < 0.3,
            "{mean} {sd}"
        );
        let scan = apply(
            &img,
            &Effects {
                grain: 0.1,
                dust_per_mp: 5000.0,
                scratches: 2,
                seed: 9,
                channels: Channels::Grey,
                ..Default::default()
            },
        );
        assert_eq!(scan.len(), 20_000);
        assert!(
            scan.iter()
                .filter(|&&v| v == 235 || v == 20 || v == 230 || v == 30)
                .count()
                > 50
        );
    }
}
