//! The two passes shared by every descriptor: detect (scale space, extrema, orientation) over all
//! octaves, apply the keypoint budget, then describe only the keypoints kept.
//!
//! Describing needs the Gaussian layers of the detection pass. They are kept between the passes
//! while they fit in a quarter of the memory budget, and recomputed band by band otherwise: small images
//! pay nothing, 100 MP scans stay within the budget.

use std::collections::{BTreeMap, HashSet};

use rayon::prelude::*;
use timesift_core::Keypoint;

use crate::FeatureError;
use crate::detect::{ExtremumTests, SCALE_SLACK, find_extrema};
use crate::image::{GreyImage, Mask, Plane};
use crate::limit::select_spread;
use crate::options::{DetectorOptions, Orientation};
use crate::orientation::orientations;
use crate::pyramid::{Band, Octave, PlanePool, ScaleSpace, first_octave, octave_is_usable};

/// Images need at least this many pixels on each side.
pub const MIN_IMAGE_SIDE: usize = 16;

/// A keypoint in the coordinates of the Gaussian layer it is described from (band-local rows,
/// pixel centres at integer indices), with its σ in that layer's pixels.
#[derive(Debug, Clone, Copy)]
pub(crate) struct LocalKeypoint {
    /// f64, so that fractional parts do not depend on the band's first row.
    pub x: f64,
    pub y: f64,
    pub sigma: f32,
    pub angle: f32,
}

/// A descriptor computed from one Gaussian layer around a keypoint.
pub(crate) trait Describer: Sync {
    type Elem: Copy + Default + Send + Sync;
    /// Values per descriptor (0: detection only).
    fn width(&self) -> usize;
    /// How far the descriptor reads from the keypoint, in units of its σ.
    fn support(&self) -> f64;
    /// Writes the descriptor of `keypoint` into `out` (`width()` values).
    fn describe(&self, layer: &Plane, keypoint: &LocalKeypoint, out: &mut [Self::Elem]);
}

/// A detected keypoint with what describing it needs.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    keypoint: Keypoint,
    octave: usize,
    /// Refined layer (fractional) in its octave.
    s: f64,
    /// Octave row of the sample refinement settled on.
    row: usize,
    band: usize,
    layer: usize,
    x: f64,
    y: f64,
    sigma: f64,
}

/// What detection in one band yields.
struct BandResult {
    found: Vec<Candidate>,
    /// The band's rows of the next octave's base.
    next_rows: Vec<f32>,
    /// Gaussian layers 1 ..= L + 1, when kept for description.
    kept: Option<Vec<Plane>>,
}

/// Members of one band to describe: (output slot, candidate index).
type BandMembers = ((usize, usize), Vec<(usize, usize)>);

/// What one octave leaves for the description pass.
struct OctaveRecord {
    octave: Octave,
    bands: Vec<Band>,
    /// Gaussian layers 1 ..= L + 1 of each band, when kept.
    kept: Vec<Option<Vec<Plane>>>,
}

/// Detects, limits and describes. Without a limit, keypoints come by octave, then row; with one,
/// in the order the budget took them (see [`crate::limit`]).
pub(crate) fn extract<D: Describer>(
    image: &GreyImage,
    mask: Option<&Mask>,
    options: &DetectorOptions,
    describer: &D,
) -> Result<(Vec<Keypoint>, Vec<D::Elem>), FeatureError> {
    options.validate()?;
    let (width, height) = (image.width(), image.height());
    if let Some(mask) = mask {
        mask.check_size(width, height)?;
    }
    if width.min(height) < MIN_IMAGE_SIDE {
        return Err(FeatureError::TooSmall {
            width,
            height,
            min: MIN_IMAGE_SIDE,
        });
    }
    let space = ScaleSpace::new(options, describer.support());
    let layers = space.layers;
    let tests = ExtremumTests {
        layers,
        prefilter: (0.5 * options.contrast_threshold / layers as f64) as f32,
        contrast: options.contrast_threshold,
        edge_ratio: options.edge_ratio,
    };
    let keep_layers = describer.width() > 0;
    // A quarter of the budget keeps finished bands' layers; detection bands get half (see
    // `ScaleSpace::bands`); the rest is headroom for the recomputation in the description pass.
    let mut keep_budget = options.memory_budget / 4;
    let mut records: Vec<OctaveRecord> = Vec::new();
    let mut candidates: Vec<Candidate> = Vec::new();
    let pool = PlanePool::default();
    let mut octave = first_octave(image, options);
    while octave_is_usable(octave.base.width, octave.base.height) {
        let (w, h) = (octave.base.width, octave.base.height);
        let bands = space.bands(w, h);
        let keep: Vec<bool> = bands
            .iter()
            .map(|band| {
                let bytes = (layers + 1) * w * band.rows.len() * std::mem::size_of::<f32>();
                let fits = keep_layers && bytes <= keep_budget;
                if fits {
                    keep_budget -= bytes;
                }
                fits
            })
            .collect();
        let (next_w, next_h) = (w / 2, h / 2);
        let slot = records.len();
        let per_band: Vec<BandResult> = bands
            .par_iter()
            .enumerate()
            .map(|(b, band)| {
                let space = &space;
                let mut stack = space.stack(&octave.base, band, layers + 3, &pool);
                let last = !octave_is_usable(next_w, next_h);
                let found: Vec<Candidate> = find_extrema(&stack, band, h, last, &tests)
                    .into_par_iter()
                    .flat_map_iter(|e| {
                        let space = &space;
                        let step = octave.step();
                        let x = e.x * step + 0.5;
                        let y = e.y * step + 0.5;
                        let allowed = mask.is_none_or(|m| m.allows(x, y));
                        // Orientation and descriptor windows scale with the layer's σ (Lowe's
                        // convention); `Keypoint::scale` reports the blob's σ, half a layer up
                        // (the DoG between two layers peaks there).
                        let sigma = space.layer_sigma(e.s);
                        let layer = &stack.gauss[e.layer];
                        let angles = match (allowed, options.orientation) {
                            (false, _) => Vec::new(),
                            (true, Orientation::Upright) => vec![0.0],
                            (true, Orientation::Dominant { peak_ratio }) => orientations(
                                layer,
                                e.x,
                                e.y - stack.row0 as f64,
                                sigma,
                                peak_ratio as f32,
                            ),
                        };
                        angles.into_iter().map(move |angle| Candidate {
                            keypoint: Keypoint {
                                x,
                                y,
                                scale: space.layer_sigma(e.s + 0.5) * step,
                                orientation: angle as f64,
                                response: e.contrast as f32,
                                octave: octave.index as i16,
                            },
                            octave: slot,
                            s: e.s,
                            row: e.row,
                            band: b,
                            layer: e.layer,
                            x: e.x,
                            y: e.y,
                            sigma,
                        })
                    })
                    .collect();
                let next = space.decimate_core(&stack, band, next_h);
                let kept = keep[b].then(|| stack.gauss.drain(1..=layers + 1).collect());
                stack.recycle(&pool);
                BandResult {
                    found,
                    next_rows: next,
                    kept,
                }
            })
            .collect();
        let mut next = Plane {
            width: next_w,
            height: next_h,
            data: Vec::with_capacity(next_w * next_h),
        };
        let mut kept = Vec::with_capacity(bands.len());
        for result in per_band {
            candidates.extend(result.found);
            next.data.extend(result.next_rows);
            kept.push(result.kept);
        }
        let next_index = octave.index + 1;
        records.push(OctaveRecord {
            octave,
            bands,
            kept,
        });
        octave = Octave {
            index: next_index,
            base: next,
        };
    }
    // Refinement can lead two starting samples to the same keypoint.
    let mut seen = HashSet::new();
    candidates.retain(|c| {
        let k = &c.keypoint;
        seen.insert((
            k.x.to_bits(),
            k.y.to_bits(),
            k.scale.to_bits(),
            k.orientation.to_bits(),
        ))
    });
    drop_octave_duplicates(&mut candidates, &records, layers);
    // One order whatever the bands: a band also lists extrema that started beyond its core, so
    // the order of discovery depends on where bands begin.
    candidates.sort_by(|a, b| {
        (a.octave, a.row, a.layer)
            .cmp(&(b.octave, b.row, b.layer))
            .then(a.x.total_cmp(&b.x))
            .then(a.y.total_cmp(&b.y))
            .then(a.s.total_cmp(&b.s))
            .then(a.keypoint.orientation.total_cmp(&b.keypoint.orientation))
    });
    let selected: Vec<usize> = match options.limit {
        Some(limit) => {
            let points: Vec<(f64, f64, f32)> = candidates
                .iter()
                .map(|c| (c.keypoint.x, c.keypoint.y, c.keypoint.response))
                .collect();
            select_spread(&points, width, height, limit.max, limit.cells, limit.spread)
        }
        None => (0..candidates.len()).collect(),
    };
    let keypoints: Vec<Keypoint> = selected.iter().map(|&i| candidates[i].keypoint).collect();
    let descriptor_width = describer.width();
    let mut descriptors = vec![D::Elem::default(); selected.len() * descriptor_width];
    if descriptor_width == 0 || selected.is_empty() {
        return Ok((keypoints, descriptors));
    }
    let mut groups: BTreeMap<(usize, usize), Vec<(usize, usize)>> = BTreeMap::new();
    for (slot, &i) in selected.iter().enumerate() {
        let c = &candidates[i];
        groups
            .entry((c.octave, c.band))
            .or_default()
            .push((slot, i));
    }
    let groups: Vec<BandMembers> = groups.into_iter().collect();
    let described: Vec<(Vec<usize>, Vec<D::Elem>)> = groups
        .par_iter()
        .map(|((o, b), members)| {
            let record = &records[*o];
            let band = &record.bands[*b];
            let recomputed;
            let layer_planes: &[Plane] = match &record.kept[*b] {
                Some(planes) => planes,
                None => {
                    let mut stack = space.stack(&record.octave.base, band, layers + 1, &pool);
                    recomputed = stack.gauss.drain(1..).collect::<Vec<_>>();
                    stack.recycle(&pool);
                    &recomputed
                }
            };
            let row0 = band.rows.start as f64;
            let mut out = vec![D::Elem::default(); members.len() * descriptor_width];
            out.par_chunks_mut(descriptor_width)
                .zip(members.par_iter())
                .for_each(|(dst, &(_, i))| {
                    let c = &candidates[i];
                    let local = LocalKeypoint {
                        x: c.x,
                        y: c.y - row0,
                        sigma: c.sigma as f32,
                        angle: c.keypoint.orientation as f32,
                    };
                    describer.describe(&layer_planes[c.layer - 1], &local, dst);
                });
            (members.iter().map(|m| m.0).collect(), out)
        })
        .collect();
    for (slots, values) in described {
        for (slot, value) in slots.iter().zip(values.chunks(descriptor_width)) {
            descriptors[slot * descriptor_width..(slot + 1) * descriptor_width]
                .copy_from_slice(value);
        }
    }
    Ok((keypoints, descriptors))
}

/// Removes keypoints found twice, by the top layers of one octave and the bottom layers of the
/// next (see `SCALE_SLACK`): the octave whose range holds the finer octave's fit keeps it.
fn drop_octave_duplicates(
    candidates: &mut Vec<Candidate>,
    records: &[OctaveRecord],
    layers: usize,
) {
    let top = layers as f64 + 0.5;
    let mut drop = vec![false; candidates.len()];
    for o in 0..records.len().saturating_sub(1) {
        let step = records[o + 1].octave.step();
        let mut lower: Vec<usize> = (0..candidates.len())
            .filter(|&i| candidates[i].octave == o + 1 && candidates[i].s < 0.5 + SCALE_SLACK)
            .collect();
        lower.sort_by(|&a, &b| {
            candidates[a]
                .keypoint
                .x
                .total_cmp(&candidates[b].keypoint.x)
        });
        let reach = 0.75 * step;
        for i in (0..candidates.len())
            .filter(|&i| candidates[i].octave == o && candidates[i].s >= top - SCALE_SLACK)
        {
            let a = candidates[i];
            let first = lower.partition_point(|&j| candidates[j].keypoint.x < a.keypoint.x - reach);
            for &j in &lower[first..] {
                let b = candidates[j];
                if b.keypoint.x > a.keypoint.x + reach {
                    break;
                }
                let same_place = (b.keypoint.y - a.keypoint.y).abs() <= reach;
                let same_scale = (a.s - (b.s + layers as f64)).abs() < 0.5;
                if same_place && same_scale {
                    if a.s < top {
                        drop[j] = true;
                    } else {
                        drop[i] = true;
                    }
                }
            }
        }
    }
    let mut index = 0;
    candidates.retain(|_| {
        index += 1;
        !drop[index - 1]
    });
}

/// Detection only: no descriptor.
pub(crate) struct NoDescriptor;

impl Describer for NoDescriptor {
    type Elem = u8;
    fn width(&self) -> usize {
        0
    }
    fn support(&self) -> f64 {
        0.0
    }
    fn describe(&self, _: &Plane, _: &LocalKeypoint, _: &mut [u8]) {}
}
