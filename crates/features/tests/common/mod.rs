//! Shared helpers of the invariance tests: a real photo, a similarity warp with a brightness
//! change, and the keypoint correspondences the warp implies.

#![allow(dead_code)]

use std::path::PathBuf;

use timesift_core::Keypoint;

/// A grey image owned by the test.
pub struct Grey {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

/// The first `lund` photo (1024 × 768), read in place from ../shared/data.
pub fn lund_photo() -> Grey {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/opensfm/lund/images/01.jpg");
    let image =
        timesift_io::image::read_grey(&path).expect("../shared/data/opensfm/lund is present");
    Grey {
        width: image.width as usize,
        height: image.height as usize,
        data: image.data,
    }
}

/// A similarity of the image plane: p_b = centre_b + scale · R(angle) · (p_a − centre_a), in
/// docs/design.md pixel coordinates.
#[derive(Debug, Clone, Copy)]
pub struct Similarity {
    pub angle: f64,
    pub scale: f64,
    pub centre_a: (f64, f64),
    pub centre_b: (f64, f64),
}

impl Similarity {
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        let (dx, dy) = (x - self.centre_a.0, y - self.centre_a.1);
        let (s, c) = self.angle.sin_cos();
        (
            self.centre_b.0 + self.scale * (c * dx - s * dy),
            self.centre_b.1 + self.scale * (s * dx + c * dy),
        )
    }

    pub fn invert(&self, x: f64, y: f64) -> (f64, f64) {
        let (dx, dy) = (
            (x - self.centre_b.0) / self.scale,
            (y - self.centre_b.1) / self.scale,
        );
        let (s, c) = self.angle.sin_cos();
        (
            self.centre_a.0 + c * dx + s * dy,
            self.centre_a.1 - s * dx + c * dy,
        )
    }
}

/// `a` warped by a rotation `angle` and a scale `scale` about its centre onto a canvas scaled by
/// `scale`, with brightness `gain · I + offset`; outside the source the canvas is mid-grey.
/// Bicubic resampling (Keys, a = −0.5): bilinear would blur by a varying amount across the
/// canvas. Only magnifications are used, so there is no aliasing to worry about.
pub fn warp(a: &Grey, angle: f64, scale: f64, gain: f32, offset: f32) -> (Grey, Similarity) {
    let width = (a.width as f64 * scale).round() as usize;
    let height = (a.height as f64 * scale).round() as usize;
    let t = Similarity {
        angle,
        scale,
        centre_a: (a.width as f64 / 2.0, a.height as f64 / 2.0),
        centre_b: (width as f64 / 2.0, height as f64 / 2.0),
    };
    let mut data = vec![0.5f32; width * height];
    for row in 0..height {
        for col in 0..width {
            let (x, y) = t.invert(col as f64 + 0.5, row as f64 + 0.5);
            let (u, v) = (x - 0.5, y - 0.5);
            if u < 0.0 || v < 0.0 || u > (a.width - 1) as f64 || v > (a.height - 1) as f64 {
                continue;
            }
            let value = bicubic(a, u, v);
            data[row * width + col] = gain * value + offset;
        }
    }
    (
        Grey {
            width,
            height,
            data,
        },
        t,
    )
}

/// For each keypoint of `a`, the index of a keypoint of `b` at its warped position (within
/// `tolerance` pixels of b) and scale (ratio within 20 %), if any.
pub fn repeated(
    a: &[Keypoint],
    b: &[Keypoint],
    t: &Similarity,
    tolerance: f64,
) -> Vec<Option<usize>> {
    a.iter()
        .map(|ka| {
            let (x, y) = t.apply(ka.x, ka.y);
            let scale = ka.scale * t.scale;
            b.iter()
                .enumerate()
                .filter(|(_, kb)| {
                    (kb.x - x).hypot(kb.y - y) <= tolerance
                        && (kb.scale / scale).ln().abs() < 0.2f64.ln_1p()
                })
                .min_by(|(_, p), (_, q)| {
                    (p.x - x)
                        .hypot(p.y - y)
                        .total_cmp(&(q.x - x).hypot(q.y - y))
                })
                .map(|(i, _)| i)
        })
        .collect()
}

/// Angle difference wrapped to [0, π].
pub fn angle_error(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(std::f64::consts::TAU);
    d.min(std::f64::consts::TAU - d)
}

/// Keys' cubic convolution at index coordinates (u, v), borders clamped.
fn bicubic(a: &Grey, u: f64, v: f64) -> f32 {
    let weights = |t: f64| {
        let kernel = |x: f64| {
            let x = x.abs();
            if x < 1.0 {
                1.5 * x.powi(3) - 2.5 * x * x + 1.0
            } else if x < 2.0 {
                -0.5 * x.powi(3) + 2.5 * x * x - 4.0 * x + 2.0
            } else {
                0.0
            }
        };
        [kernel(1.0 + t), kernel(t), kernel(1.0 - t), kernel(2.0 - t)]
    };
    let (u0, v0) = (u.floor(), v.floor());
    let (wu, wv) = (weights(u - u0), weights(v - v0));
    let mut value = 0.0;
    for (j, wy) in wv.iter().enumerate() {
        let r = (v0 as isize + j as isize - 1).clamp(0, a.height as isize - 1) as usize;
        for (i, wx) in wu.iter().enumerate() {
            let c = (u0 as isize + i as isize - 1).clamp(0, a.width as isize - 1) as usize;
            value += wx * wy * a.data[r * a.width + c] as f64;
        }
    }
    value as f32
}
