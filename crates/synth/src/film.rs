//! Film scans: a photograph on film inside a frame of fiducial marks, with the frame's data
//! strip, scanned with a transform of its own (shift, rotation, film shrinkage, differential
//! scale and shear), as archival aerial photographs come. The camera of an epoch describes the
//! photograph in *frame pixels* — the raster of the marks' bounding box at the scan's pixel
//! size, y down, its centre the box's centre (the convention `timesift` resamples scans to) —
//! and a scan pixel is `scan_from_frame` of a frame pixel.

use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};
use timesift_core::{BrownCamera, CameraModel, CoreError, SeededRng};

/// The shape of a fiducial mark, drawn bright on the dark film edge.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MarkPattern {
    /// A plain cross.
    Cross,
    /// A dot inside a circle.
    DotInCircle,
    /// A dot with four bars around it (as on Wild RC cameras).
    RcType,
    /// A cross with an open centre and a ring (as on Zeiss RMK cameras).
    RmkType,
}

impl MarkPattern {
    /// Whether a point at `p` (mark frame, in units of the mark's radius) is bright.
    fn inside(self, p: Vector2<f64>) -> bool {
        let r = p.norm();
        let (ax, ay) = (p.x.abs(), p.y.abs());
        match self {
            MarkPattern::Cross => (ay < 0.12 && ax < 1.0) || (ax < 0.12 && ay < 1.0),
            MarkPattern::DotInCircle => r < 0.25 || (r > 0.72 && r < 0.95),
            MarkPattern::RcType => {
                r < 0.2
                    || (ay < 0.1 && ax > 0.45 && ax < 1.0)
                    || (ax < 0.1 && ay > 0.45 && ay < 1.0)
            }
            MarkPattern::RmkType => {
                (r > 0.55 && r < 0.68)
                    || (ay < 0.08 && ax > 0.3 && ax < 1.0)
                    || (ax < 0.08 && ay > 0.3 && ay < 1.0)
            }
        }
    }
}

/// Brightness of the unexposed film edge and of the marks (linear, before exposure).
const FILM_BASE: f64 = 0.03;
const MARK: f64 = 0.75;

/// How an epoch's photographs sit on film and were scanned.
#[derive(Debug, Clone, PartialEq)]
pub struct FilmSpec {
    /// The marks' shape.
    pub pattern: MarkPattern,
    /// Mark names and certificate positions (mm, x right, y up; the origin is the
    /// certificate's own).
    pub marks: Vec<(String, Vector2<f64>)>,
    /// Scan pixel size, mm.
    pub pixel_mm: f64,
    /// Mark radius, frame pixels.
    pub mark_radius: f64,
    /// Width of the dark film edge inside the frame (between the photograph and the frame's
    /// edges, where the marks sit), frame pixels.
    pub edge: f64,
    /// Scanned film around the frame, on each side, pixels.
    pub border: usize,
    /// Height of the data strip below the frame's border, pixels.
    pub strip: usize,
    /// Certificate principal point, mm.
    pub principal_point_mm: Vector2<f64>,
}

impl FilmSpec {
    /// The film of a camera whose frame raster is `camera.width × camera.height` pixels of
    /// `pixel_mm`: eight marks (corners and sides) on the frame's edges, the certificate's
    /// origin off the frame's centre, the principal point where the camera's `cx`, `cy` put it.
    pub fn eight_marks(
        camera: &BrownCamera,
        pixel_mm: f64,
        pattern: MarkPattern,
        origin_mm: Vector2<f64>,
    ) -> FilmSpec {
        let (w, h) = (camera.width as f64, camera.height as f64);
        let (hx, hy) = (0.5 * w * pixel_mm, 0.5 * h * pixel_mm);
        let marks = [
            ("1", -hx, hy),
            ("2", 0.0, hy),
            ("3", hx, hy),
            ("4", hx, 0.0),
            ("5", hx, -hy),
            ("6", 0.0, -hy),
            ("7", -hx, -hy),
            ("8", -hx, 0.0),
        ]
        .into_iter()
        .map(|(n, x, y)| (n.to_string(), Vector2::new(x, y) - origin_mm))
        .collect();
        let scale = w.max(h) / 512.0;
        FilmSpec {
            pattern,
            marks,
            pixel_mm,
            mark_radius: 8.0 * scale,
            edge: 12.0 * scale,
            border: (44.0 * scale).round() as usize,
            strip: (24.0 * scale).round() as usize,
            principal_point_mm: Vector2::new(camera.cx, -camera.cy) * pixel_mm - origin_mm,
        }
    }

    /// The centre of the marks' bounding box, mm: the frame's centre.
    fn centre_mm(&self) -> Vector2<f64> {
        let (mut lo, mut hi) = (self.marks[0].1, self.marks[0].1);
        for (_, m) in &self.marks {
            lo = lo.inf(m);
            hi = hi.sup(m);
        }
        0.5 * (lo + hi)
    }

    /// Frame pixel of a certificate position.
    pub fn frame_from_mm(&self, camera: &BrownCamera, mm: &Vector2<f64>) -> Vector2<f64> {
        let d = (mm - self.centre_mm()) / self.pixel_mm;
        Vector2::new(
            0.5 * camera.width as f64 + d.x,
            0.5 * camera.height as f64 - d.y,
        )
    }

    /// Scan size (width, height) for a camera.
    pub fn scan_size(&self, camera: &BrownCamera) -> (u32, u32) {
        (
            camera.width + 2 * self.border as u32,
            camera.height + 2 * self.border as u32 + self.strip as u32,
        )
    }

    /// A scan transform as a scanner makes them: the frame centred on its place in the scan,
    /// shifted by tens of pixels, rotated by up to 1°, the film shrunk by a few 1e-4 with a
    /// differential scale and a shear.
    pub fn draw_scan(&self, camera: &BrownCamera, rng: &mut SeededRng) -> ScanGeometry {
        let clamp = |v: f64, m: f64| v.clamp(-m, m);
        let scale = camera.width.max(camera.height) as f64 / 512.0;
        let shift = Vector2::new(
            clamp(10.0 * scale * rng.normal(), 25.0 * scale),
            clamp(10.0 * scale * rng.normal(), 25.0 * scale),
        );
        let angle = clamp(0.4f64.to_radians() * rng.normal(), 1f64.to_radians());
        let shrink = 1.0 - rng.uniform_range(1e-4, 6e-4);
        let differential = rng.uniform_range(-2e-4, 2e-4);
        let shear = rng.uniform_range(-3e-4, 3e-4);
        let (s, c) = angle.sin_cos();
        let linear = Matrix2::new(c, -s, s, c)
            * Matrix2::new(
                shrink * (1.0 + differential),
                shear,
                0.0,
                shrink * (1.0 - differential),
            );
        let frame_centre = Vector2::new(0.5 * camera.width as f64, 0.5 * camera.height as f64);
        let place = Vector2::new(self.border as f64, self.border as f64) + frame_centre + shift;
        let mut scan_from_frame = Matrix3::identity();
        scan_from_frame
            .fixed_view_mut::<2, 2>(0, 0)
            .copy_from(&linear);
        scan_from_frame
            .fixed_view_mut::<2, 1>(0, 2)
            .copy_from(&(place - linear * frame_centre));
        ScanGeometry {
            scan_from_frame,
            strip_seed: rng.next_u64(),
        }
    }

    /// Film brightness (linear) at a frame position outside the photograph: the film edge, a
    /// mark, or the data strip.
    pub fn film_value(
        &self,
        camera: &BrownCamera,
        marks_px: &[Vector2<f64>],
        strip: &[Strip],
        p: &Vector2<f64>,
    ) -> f64 {
        for m in marks_px {
            let d = (p - m) / self.mark_radius;
            if d.norm_squared() < 1.0 && self.pattern.inside(d) {
                return MARK;
            }
        }
        let below = p.y - camera.height as f64 - 0.3 * self.border as f64;
        if below > 0.0 && strip.iter().any(|s| s.contains(p.x, below)) {
            return MARK;
        }
        FILM_BASE
    }

    /// Whether a frame position lies on the photograph.
    pub fn on_photo(&self, camera: &BrownCamera, p: &Vector2<f64>) -> bool {
        p.x >= self.edge
            && p.y >= self.edge
            && p.x <= camera.width as f64 - self.edge
            && p.y <= camera.height as f64 - self.edge
    }

    /// The data strip of one frame: digits (bars), a clock and a frame counter, random per
    /// frame.
    pub fn strip(&self, camera: &BrownCamera, seed: u64) -> Vec<Strip> {
        let mut rng = SeededRng::new(seed);
        let height = 0.6 * self.strip as f64;
        let mut out = vec![Strip::Ring {
            centre: (0.15 * camera.width as f64, 0.5 * height),
            radius: 0.45 * height,
        }];
        let mut x = 0.3 * camera.width as f64;
        while x < 0.85 * camera.width as f64 {
            let w = rng.uniform_range(0.15, 0.5) * height;
            if rng.uniform() < 0.7 {
                out.push(Strip::Bar {
                    x0: x,
                    x1: x + w,
                    y0: rng.uniform_range(0.0, 0.3) * height,
                    y1: height * rng.uniform_range(0.7, 1.0),
                });
            }
            x += w + 0.2 * height;
        }
        out
    }

    /// The template a user would cut from a scan: the mark, centred on the template's centre,
    /// (2 ⌈r⌉ + 5)² pixels of linear brightness, sampled 8 × 8 per pixel.
    pub fn template(&self) -> (usize, Vec<f64>) {
        let size = 2 * self.mark_radius.ceil() as usize + 5;
        let c = 0.5 * size as f64;
        let mut out = vec![0.0; size * size];
        for j in 0..size {
            for i in 0..size {
                let mut sum = 0.0;
                for s in 0..64 {
                    let p = Vector2::new(
                        i as f64 + ((s % 8) as f64 + 0.5) / 8.0 - c,
                        j as f64 + ((s / 8) as f64 + 0.5) / 8.0 - c,
                    ) / self.mark_radius;
                    sum += if p.norm_squared() < 1.0 && self.pattern.inside(p) {
                        MARK
                    } else {
                        FILM_BASE
                    };
                }
                out[j * size + i] = sum / 64.0;
            }
        }
        (size, out)
    }

    /// Mark positions in frame pixels.
    pub fn marks_px(&self, camera: &BrownCamera) -> Vec<Vector2<f64>> {
        self.marks
            .iter()
            .map(|(_, m)| self.frame_from_mm(camera, m))
            .collect()
    }
}

/// An element of the data strip, in frame pixels below the frame's border.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Strip {
    /// A filled rectangle.
    Bar {
        /// Left.
        x0: f64,
        /// Right.
        x1: f64,
        /// Top.
        y0: f64,
        /// Bottom.
        y1: f64,
    },
    /// A clock's ring.
    Ring {
        /// Centre.
        centre: (f64, f64),
        /// Radius.
        radius: f64,
    },
}

impl Strip {
    fn contains(&self, x: f64, y: f64) -> bool {
        match *self {
            Strip::Bar { x0, x1, y0, y1 } => x >= x0 && x <= x1 && y >= y0 && y <= y1,
            Strip::Ring { centre, radius } => {
                let r = (x - centre.0).hypot(y - centre.1);
                r > 0.8 * radius && r < radius
            }
        }
    }
}

/// Where one scan put its frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanGeometry {
    /// Frame pixels → scan pixels (affine).
    pub scan_from_frame: Matrix3<f64>,
    /// Seed of the frame's data strip.
    pub strip_seed: u64,
}

impl ScanGeometry {
    /// The scan pixel of a frame pixel.
    pub fn scan_px(&self, frame: &Vector2<f64>) -> Vector2<f64> {
        let q = self.scan_from_frame * frame.push(1.0);
        Vector2::new(q.x, q.y)
    }

    /// The frame pixel of a scan pixel.
    pub fn frame_px(&self, scan: &Vector2<f64>) -> Vector2<f64> {
        let m = self.scan_from_frame;
        let linear = Matrix2::new(m[(0, 0)], m[(0, 1)], m[(1, 0)], m[(1, 1)]);
        let inverse = linear.try_inverse().unwrap_or_else(Matrix2::identity);
        inverse * (scan - Vector2::new(m[(0, 2)], m[(1, 2)]))
    }
}

/// The photograph camera's rays at every frame pixel corner, computed once per epoch: a scan
/// samples the frame at positions of its own, and the rays between corners are bilinear (the
/// lens model is smooth at that scale: far below 1e-6 rad).
pub struct FrameRays {
    width: usize,
    rays: Vec<Option<Vector2<f64>>>,
}

impl FrameRays {
    /// The rays of `camera` at the corners of its pixels.
    pub fn new(camera: &BrownCamera) -> FrameRays {
        use rayon::prelude::*;
        let (w, h) = (camera.width as usize + 1, camera.height as usize + 1);
        let rays = (0..w * h)
            .into_par_iter()
            .map(|k| {
                let p = Vector2::new((k % w) as f64, (k / w) as f64);
                camera
                    .unproject(&p)
                    .ok()
                    .map(|r| Vector2::new(r.x / r.z, r.y / r.z))
            })
            .collect();
        FrameRays { width: w, rays }
    }

    /// The ray (z = 1) at a frame position; `None` outside the frame.
    fn ray(&self, p: &Vector2<f64>) -> Option<Vector3<f64>> {
        let h = self.rays.len() / self.width;
        let (i, j) = (p.x.floor(), p.y.floor());
        if i < 0.0 || j < 0.0 || i as usize + 1 >= self.width || j as usize + 1 >= h {
            return None;
        }
        let (fx, fy) = (p.x - i, p.y - j);
        let (i, j) = (i as usize, j as usize);
        let at = |a: usize, b: usize| self.rays[b * self.width + a];
        let r = at(i, j)? * ((1.0 - fx) * (1.0 - fy))
            + at(i + 1, j)? * (fx * (1.0 - fy))
            + at(i, j + 1)? * ((1.0 - fx) * fy)
            + at(i + 1, j + 1)? * (fx * fy);
        Some(Vector3::new(r.x, r.y, 1.0))
    }
}

/// A camera that sees through a scan: pixels of the scan, rays of the photograph's camera, no
/// ray outside the photograph (the renderer leaves those to the film).
pub struct ScanCamera<'a> {
    /// The photograph's camera (frame pixels).
    pub camera: &'a BrownCamera,
    /// Its rays.
    pub rays: &'a FrameRays,
    /// The film.
    pub film: &'a FilmSpec,
    /// The scan.
    pub scan: &'a ScanGeometry,
    /// Scan size.
    pub size: (u32, u32),
}

impl CameraModel for ScanCamera<'_> {
    fn model_name(&self) -> &'static str {
        "scan"
    }
    fn width(&self) -> u32 {
        self.size.0
    }
    fn height(&self) -> u32 {
        self.size.1
    }
    fn param_names(&self) -> &'static [&'static str] {
        self.camera.param_names()
    }
    fn params(&self, out: &mut [f64]) {
        self.camera.params(out)
    }
    fn set_params(&mut self, _: &[f64]) -> Result<(), CoreError> {
        Err(CoreError::ParameterCount {
            model: "scan",
            expected: 0,
            got: 0,
        })
    }
    fn project(&self, p_cam: &Vector3<f64>) -> Result<Vector2<f64>, CoreError> {
        Ok(self.scan.scan_px(&self.camera.project(p_cam)?))
    }
    fn project_with_jacobians(
        &self,
        p_cam: &Vector3<f64>,
        _: Option<&mut [f64]>,
    ) -> Result<(Vector2<f64>, nalgebra::Matrix2x3<f64>), CoreError> {
        let (frame, d) = self.camera.project_with_jacobians(p_cam, None)?;
        let m = self.scan.scan_from_frame;
        let linear = Matrix2::new(m[(0, 0)], m[(0, 1)], m[(1, 0)], m[(1, 1)]);
        Ok((self.scan.scan_px(&frame), linear * d))
    }
    fn unproject(&self, pixel: &Vector2<f64>) -> Result<Vector3<f64>, CoreError> {
        let frame = self.scan.frame_px(pixel);
        if !self.film.on_photo(self.camera, &frame) {
            // Off the photograph: the film is drawn there instead.
            return Err(CoreError::BehindCamera { z: 0.0 });
        }
        self.rays
            .ray(&frame)
            .ok_or(CoreError::BehindCamera { z: 0.0 })
    }
}
