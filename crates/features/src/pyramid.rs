//! The Gaussian scale space, octave by octave, in horizontal bands.
//!
//! An octave's base (its first Gaussian layer) is held whole; the other layers and the differences
//! of Gaussians exist only for one band of rows at a time, computed from the base rows of the band
//! plus a margin. The margin covers the blur kernels' reach and the descriptor's support, so every
//! value read for a keypoint whose row lies in the band's core is the value a whole-image scale
//! space would hold: banding changes memory, never results.

use std::ops::Range;

use crate::blur::{Kernel, blur, upsample2};
use crate::image::{GreyImage, Plane};
use crate::options::{DetectorOptions, Upsample};

/// Refinement moves at most one sample per step, so a keypoint lies within this many samples of
/// the extremum it started from.
pub(crate) const MAX_REFINE_STEPS: usize = 5;

/// How far (in layers) beyond the half-way point to the next octave an octave still keeps an
/// extremum. Fits of the same blob in two octaves disagree by a few hundredths of a layer; the
/// overlap makes sure one of them keeps it, and `extract` removes the duplicates.
pub(crate) const SCALE_SLACK: f64 = 0.25;

/// Keypoints closer than this to the image border (in octave pixels) are not sought, as in Lowe's
/// and OpenCV's SIFT.
pub(crate) const BORDER: usize = 5;

/// Octaves stop when the smaller side of the octave falls below this.
const MIN_OCTAVE_SIDE: usize = 2 * BORDER + 6;

/// One octave: its index (−1 for the doubled image, then 0, 1, …) and its base layer.
#[derive(Debug)]
pub(crate) struct Octave {
    pub index: i32,
    pub base: Plane,
}

impl Octave {
    /// Full-resolution pixels per octave pixel.
    pub fn step(&self) -> f64 {
        2f64.powi(self.index)
    }
}

/// Rows of an octave handled together: `core` rows own their keypoints, `rows` adds the margin.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Band {
    pub core: Range<usize>,
    pub rows: Range<usize>,
}

/// The Gaussian layers of one band. Differences of Gaussians are not stored: they are formed
/// where they are read, which saves as many planes as there are layers.
#[derive(Debug)]
pub(crate) struct BandStack {
    /// Octave row of local row 0.
    pub row0: usize,
    pub gauss: Vec<Plane>,
}

impl BandStack {
    /// The difference of Gaussians `s` (layer s+1 minus layer s) at (x, y), band-local.
    #[inline]
    pub fn dog(&self, s: usize, x: usize, y: usize) -> f32 {
        self.gauss[s + 1].at(x, y) - self.gauss[s].at(x, y)
    }

    /// Width of the planes.
    pub fn width(&self) -> usize {
        self.gauss[0].width
    }

    /// Rows of the planes.
    pub fn rows(&self) -> usize {
        self.gauss[0].height
    }

    /// Returns every plane to `pool`.
    pub fn recycle(self, pool: &PlanePool) {
        for plane in self.gauss {
            pool.give(plane.data);
        }
    }
}

/// Buffers of planes freed by one band and reused by the next (or by the next, smaller,
/// octave): the scale space of a large image otherwise spends much of its time having the kernel
/// zero fresh pages.
#[derive(Debug, Default)]
pub(crate) struct PlanePool {
    free: std::sync::Mutex<Vec<Vec<f32>>>,
}

impl PlanePool {
    /// A buffer of `len` values (contents unspecified), reused when one is large enough.
    pub fn take(&self, len: usize) -> Vec<f32> {
        let reused = {
            let mut free = self.free.lock().unwrap_or_else(|p| p.into_inner());
            let best = free
                .iter()
                .enumerate()
                .filter(|(_, v)| v.capacity() >= len)
                .min_by_key(|(_, v)| v.capacity())
                .map(|(i, _)| i);
            best.map(|i| free.swap_remove(i))
        };
        match reused {
            Some(mut v) => {
                // Shrinking or growing within capacity: no new pages.
                v.resize(len, 0.0);
                v
            }
            None => vec![0.0; len],
        }
    }

    /// Hands a buffer back for reuse.
    pub fn give(&self, buffer: Vec<f32>) {
        if buffer.capacity() > 0 {
            self.free
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .push(buffer);
        }
    }
}

/// The blur plan shared by every octave.
#[derive(Debug)]
pub(crate) struct ScaleSpace {
    pub layers: usize,
    pub sigma: f64,
    /// Kernels taking layer s−1 to layer s, s = 1 ..= layers + 3.
    pub increments: Vec<Kernel>,
    /// Rows of margin around a band's core.
    pub margin: usize,
    pub memory_budget: usize,
}

impl ScaleSpace {
    /// `support` is the descriptor's reach in units of the keypoint's σ.
    pub fn new(options: &DetectorOptions, support: f64) -> Self {
        let layers = options.layers_per_octave;
        let k = 2f64.powf(1.0 / layers as f64);
        let increments: Vec<Kernel> = (1..layers + 4)
            .map(|s| {
                let previous = options.sigma * k.powi(s as i32 - 1);
                Kernel::gaussian(previous * (k * k - 1.0).sqrt())
            })
            .collect();
        let blur_reach: usize = increments.iter().map(Kernel::radius).sum();
        // The last octave keeps keypoints up to layer L + 1 + 0.5 + SCALE_SLACK.
        let max_sigma =
            options.sigma * 2f64.powf((layers as f64 + 1.5 + SCALE_SLACK) / layers as f64);
        let descriptor_reach = (support.max(4.5) * max_sigma).ceil() as usize;
        Self {
            layers,
            sigma: options.sigma,
            increments,
            margin: blur_reach + descriptor_reach + MAX_REFINE_STEPS + 2,
            memory_budget: options.memory_budget,
        }
    }

    /// σ of layer `s` (fractional) in octave pixels.
    pub fn layer_sigma(&self, s: f64) -> f64 {
        self.sigma * 2f64.powf(s / self.layers as f64)
    }

    /// Bytes of a detection stack (all Gaussian layers) per octave row.
    fn stack_bytes_per_row(&self, width: usize) -> usize {
        (self.layers + 4) * width * std::mem::size_of::<f32>()
    }

    /// Splits an octave's rows into bands whose detection stacks fit half the memory budget when
    /// one band per thread runs at once.
    pub fn bands(&self, width: usize, height: usize) -> Vec<Band> {
        let per_row = self.stack_bytes_per_row(width);
        // Half the budget for the bands in flight, one per thread.
        let budget = self.memory_budget / 2;
        if per_row * height <= budget {
            return vec![Band {
                core: 0..height,
                rows: 0..height,
            }];
        }
        let threads = rayon::current_num_threads().max(1);
        let rows_fit = budget / (threads * per_row);
        let core = rows_fit.saturating_sub(2 * self.margin).max(64);
        (0..height)
            .step_by(core)
            .map(|start| {
                let end = (start + core).min(height);
                Band {
                    core: start..end,
                    rows: start.saturating_sub(self.margin)..(end + self.margin).min(height),
                }
            })
            .collect()
    }

    /// The Gaussian layers 0 ..= `top` of `band`, in buffers from `pool`.
    pub fn stack(&self, base: &Plane, band: &Band, top: usize, pool: &PlanePool) -> BandStack {
        let w = base.width;
        let rows = band.rows.len();
        let mut first = pool.take(w * rows);
        first.copy_from_slice(&base.data[band.rows.start * w..band.rows.end * w]);
        let mut gauss = Vec::with_capacity(top + 1);
        gauss.push(Plane {
            width: w,
            height: rows,
            data: first,
        });
        for (s, kernel) in self.increments[..top].iter().enumerate() {
            let mut next = Plane {
                width: w,
                height: rows,
                data: pool.take(w * rows),
            };
            blur(&gauss[s].data, w, kernel, &mut next);
            gauss.push(next);
        }
        BandStack {
            row0: band.rows.start,
            gauss,
        }
    }

    /// The next octave's base: layer `layers` (twice the base σ) of the band's core rows,
    /// decimated by 2; rows are those of the next octave that come from this band.
    pub fn decimate_core(&self, stack: &BandStack, band: &Band, next_height: usize) -> Vec<f32> {
        let layer = &stack.gauss[self.layers];
        let next_width = layer.width / 2;
        let mut out = Vec::new();
        for y in band
            .core
            .clone()
            .filter(|y| y % 2 == 0 && y / 2 < next_height)
        {
            let row = layer.row(y - stack.row0);
            out.extend((0..next_width).map(|x| row[2 * x]));
        }
        out
    }
}

/// The first octave's base: the image (doubled or not) blurred from its assumed blur to σ.
pub(crate) fn first_octave(image: &GreyImage, options: &DetectorOptions) -> Octave {
    let pixels = (image.width() * image.height()) as u64;
    let double = match options.upsample {
        Upsample::Never => false,
        Upsample::Always => true,
        Upsample::UpToPixels(max) => pixels <= max,
    };
    let present = if double {
        2.0 * options.assumed_blur
    } else {
        options.assumed_blur
    };
    let missing = (options.sigma * options.sigma - present * present)
        .max(0.01)
        .sqrt();
    let kernel = Kernel::gaussian(missing);
    let mut base = Plane::default();
    if double {
        let up = upsample2(image.data(), image.width());
        blur(&up.data, up.width, &kernel, &mut base);
        Octave { index: -1, base }
    } else {
        // Straight from the caller's pixels: no copy of a 100 MP image.
        blur(image.data(), image.width(), &kernel, &mut base);
        Octave { index: 0, base }
    }
}

/// Whether an octave of this size still holds keypoints.
pub(crate) fn octave_is_usable(width: usize, height: usize) -> bool {
    width.min(height) >= MIN_OCTAVE_SIDE
}
