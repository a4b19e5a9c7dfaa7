//! The changes a scene is made of, each with a closed-form volume: smooth bumps (excavations,
//! deposits, tree crowns, ice bodies, boulders), ridges (road embankments) and blocks (buildings,
//! cars). The true volume of a changed region is the sum of the closed forms, independent of any
//! grid, so that volumes integrated from the rendered surfaces can be checked against it.

use std::f64::consts::PI;

/// An elliptical bump `height · (1 − ρ²)^power` for ρ < 1, where ρ² = (x′/a)² + (y′/b)² in the
/// frame centred on `centre` and turned by `yaw`. Volume π a b height / (power + 1). A power of 2
/// or more makes the rim smooth (C¹), so a grid resolves the volume closely.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bump {
    /// Centre (x, y).
    pub centre: (f64, f64),
    /// Semi-axis along the yawed x axis.
    pub a: f64,
    /// Semi-axis along the yawed y axis.
    pub b: f64,
    /// Rotation of the axes, radians, anticlockwise from x.
    pub yaw: f64,
    /// Height at the centre (negative for a pit).
    pub height: f64,
    /// Shape exponent.
    pub power: f64,
}

impl Bump {
    /// A round bump.
    pub fn round(centre: (f64, f64), radius: f64, height: f64, power: f64) -> Bump {
        Bump {
            centre,
            a: radius,
            b: radius,
            yaw: 0.0,
            height,
            power,
        }
    }

    fn rho2(&self, x: f64, y: f64) -> f64 {
        let (dx, dy) = (x - self.centre.0, y - self.centre.1);
        // Evaluated for every ray sample in cover functions: skip the rotation when there is none.
        let (u, v) = if self.yaw == 0.0 {
            (dx, dy)
        } else {
            let (s, c) = self.yaw.sin_cos();
            (c * dx + s * dy, -s * dx + c * dy)
        };
        (u / self.a).powi(2) + (v / self.b).powi(2)
    }

    /// Height at (x, y).
    pub fn value(&self, x: f64, y: f64) -> f64 {
        let r2 = self.rho2(x, y);
        if r2 >= 1.0 {
            0.0
        } else {
            self.height * (1.0 - r2).powf(self.power)
        }
    }

    /// Exact volume (signed like `height`).
    pub fn volume(&self) -> f64 {
        PI * self.a * self.b * self.height / (self.power + 1.0)
    }

    /// Whether (x, y) is inside the footprint grown by `margin`.
    pub fn covers(&self, x: f64, y: f64, margin: f64) -> bool {
        let grown = Bump {
            a: self.a + margin,
            b: self.b + margin,
            ..*self
        };
        grown.rho2(x, y) < 1.0
    }

    /// A polygon containing the footprint grown by `margin` (circumscribed 48-gon).
    pub fn footprint(&self, margin: f64) -> Vec<[f64; 2]> {
        let n = 48;
        let grow = 1.0 / (PI / n as f64).cos();
        let (s, c) = self.yaw.sin_cos();
        (0..n)
            .map(|k| {
                let t = 2.0 * PI * k as f64 / n as f64;
                let (u, v) = (
                    (self.a + margin) * grow * t.cos(),
                    (self.b + margin) * grow * t.sin(),
                );
                [self.centre.0 + c * u - s * v, self.centre.1 + s * u + c * v]
            })
            .collect()
    }
}

/// A straight embankment from `start` to `end`: a trapezoid cross-section (flat top of
/// `top_width`, linear sides down to `base_width`) times a trapezoid long profile (linear ramps of
/// `ramp` length at both ends). Volume height · (top + base)/2 · (length − ramp).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ridge {
    /// One end of the axis.
    pub start: (f64, f64),
    /// The other end.
    pub end: (f64, f64),
    /// Height of the crest.
    pub height: f64,
    /// Width of the flat crest.
    pub top_width: f64,
    /// Width at the foot.
    pub base_width: f64,
    /// Length of each end ramp.
    pub ramp: f64,
}

impl Ridge {
    fn along_across(&self, x: f64, y: f64) -> (f64, f64, f64) {
        let (dx, dy) = (self.end.0 - self.start.0, self.end.1 - self.start.1);
        let length = dx.hypot(dy);
        let (ux, uy) = (dx / length, dy / length);
        let (px, py) = (x - self.start.0, y - self.start.1);
        (px * ux + py * uy, -px * uy + py * ux, length)
    }

    /// Height at (x, y).
    pub fn value(&self, x: f64, y: f64) -> f64 {
        let (s, d, length) = self.along_across(x, y);
        let across = {
            let d = d.abs();
            let (t, b) = (0.5 * self.top_width, 0.5 * self.base_width);
            if d <= t {
                1.0
            } else if d >= b {
                0.0
            } else {
                (b - d) / (b - t)
            }
        };
        let along = if s <= 0.0 || s >= length {
            0.0
        } else {
            (s / self.ramp).min((length - s) / self.ramp).min(1.0)
        };
        self.height * across * along
    }

    /// Exact volume.
    pub fn volume(&self) -> f64 {
        let (_, _, length) = self.along_across(self.end.0, self.end.1);
        self.height * 0.5 * (self.top_width + self.base_width) * (length - self.ramp)
    }

    /// The footprint grown by `margin`, a rectangle.
    pub fn footprint(&self, margin: f64) -> Vec<[f64; 2]> {
        let (_, _, length) = self.along_across(self.end.0, self.end.1);
        let (ux, uy) = (
            (self.end.0 - self.start.0) / length,
            (self.end.1 - self.start.1) / length,
        );
        let (nx, ny) = (-uy, ux);
        let half = 0.5 * self.base_width + margin;
        let (s0, s1) = (-margin, length + margin);
        [(s0, -half), (s1, -half), (s1, half), (s0, half)]
            .iter()
            .map(|&(s, d)| {
                [
                    self.start.0 + s * ux + d * nx,
                    self.start.1 + s * uy + d * ny,
                ]
            })
            .collect()
    }

    /// Whether (x, y) is inside the footprint grown by `margin`.
    pub fn covers(&self, x: f64, y: f64, margin: f64) -> bool {
        let (s, d, length) = self.along_across(x, y);
        s > -margin && s < length + margin && d.abs() < 0.5 * self.base_width + margin
    }
}

/// An axis-aligned box standing on level ground at `base` up to `top`: a building or a car. Its
/// volume above the ground is (max − min) area × (top − base).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Block {
    /// South-west corner (x, y).
    pub min: (f64, f64),
    /// North-east corner (x, y).
    pub max: (f64, f64),
    /// Ground level under it.
    pub base: f64,
    /// Roof level.
    pub top: f64,
}

impl Block {
    /// Exact volume above the ground.
    pub fn volume(&self) -> f64 {
        (self.max.0 - self.min.0) * (self.max.1 - self.min.1) * (self.top - self.base)
    }

    /// Whether (x, y) is inside the footprint grown by `margin`.
    pub fn covers(&self, x: f64, y: f64, margin: f64) -> bool {
        x > self.min.0 - margin
            && x < self.max.0 + margin
            && y > self.min.1 - margin
            && y < self.max.1 + margin
    }

    /// The footprint grown by `margin`.
    pub fn footprint(&self, margin: f64) -> Vec<[f64; 2]> {
        let (x0, y0, x1, y1) = (
            self.min.0 - margin,
            self.min.1 - margin,
            self.max.0 + margin,
            self.max.1 + margin,
        );
        vec![[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
    }

    /// The mesh: roof and four walls (from `base − 0.5` so no gap shows at the foot).
    pub fn mesh(&self) -> (Vec<nalgebra::Vector3<f64>>, Vec<[u32; 3]>) {
        use nalgebra::Vector3;
        let (x0, y0, x1, y1) = (self.min.0, self.min.1, self.max.0, self.max.1);
        let (z0, z1) = (self.base - 0.5, self.top);
        let v = vec![
            Vector3::new(x0, y0, z0),
            Vector3::new(x1, y0, z0),
            Vector3::new(x1, y1, z0),
            Vector3::new(x0, y1, z0),
            Vector3::new(x0, y0, z1),
            Vector3::new(x1, y0, z1),
            Vector3::new(x1, y1, z1),
            Vector3::new(x0, y1, z1),
        ];
        let t = vec![
            [4, 5, 6],
            [4, 6, 7],
            [0, 1, 5],
            [0, 5, 4],
            [1, 2, 6],
            [1, 6, 5],
            [2, 3, 7],
            [2, 7, 6],
            [3, 0, 4],
            [3, 4, 7],
        ];
        (v, t)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Midpoint-rule integral over a fine grid.
    fn integrate(f: impl Fn(f64, f64) -> f64, x0: f64, x1: f64, y0: f64, y1: f64) -> f64 {
        let n = 2000;
        let (hx, hy) = ((x1 - x0) / n as f64, (y1 - y0) / n as f64);
        let mut sum = 0.0;
        for j in 0..n {
            for i in 0..n {
                sum += f(x0 + (i as f64 + 0.5) * hx, y0 + (j as f64 + 0.5) * hy);
            }
        }
        sum * hx * hy
    }

    #[test]
    fn closed_form_volumes_match_quadrature() {
        let bump = Bump {
            centre: (3.0, -2.0),
            a: 4.0,
            b: 2.5,
            yaw: 0.6,
            height: -1.7,
            power: 2.0,
        };
        let q = integrate(|x, y| bump.value(x, y), -2.0, 8.0, -7.0, 3.0);
        assert!((q / bump.volume() - 1.0).abs() < 1e-4, "{q}");
        let ridge = Ridge {
            start: (0.0, 0.0),
            end: (30.0, 10.0),
            height: 2.0,
            top_width: 4.0,
            base_width: 10.0,
            ramp: 5.0,
        };
        let q = integrate(|x, y| ridge.value(x, y), -10.0, 40.0, -10.0, 20.0);
        assert!((q / ridge.volume() - 1.0).abs() < 1e-4, "{q}");
        for (x, y) in [(15.0, 5.0), (1.0, 0.5), (29.0, 9.0)] {
            assert!(ridge.covers(x, y, 0.0));
            assert!(timesift_io::wkt::ring_contains(&ridge.footprint(0.0), x, y));
        }
        assert!(bump.covers(3.0, -2.0, 0.0) && !bump.covers(3.0, 2.0, 0.0));
        assert!(timesift_io::wkt::ring_contains(
            &bump.footprint(0.0),
            3.0,
            -2.0
        ));
    }
}
