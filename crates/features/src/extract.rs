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
use crate::detect::{Extremum, ExtremumTests, find_extrema};
use crate::image::{GreyImage, Mask, Plane};
use crate::limit::select_spread;
use crate::options::{DetectorOptions, Orientation};
use crate::orientation::orientations;
use crate::pyramid::SCALE_SLACK;
use crate::pyramid::{
    Band, BandStack, Octave, PlanePool, ScaleSpace, first_octave, octave_is_usable,
};

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
    let pool = PlanePool::default();
    let detection = Detection {
        space: &space,
        tests: ExtremumTests {
            layers,
            prefilter: (0.5 * options.contrast_threshold / layers as f64) as f32,
            contrast: options.contrast_threshold,
            edge_ratio: options.edge_ratio,
        },
        mask,
        options,
        pool: &pool,
    };
    let (records, mut candidates) = detection.detect_octaves(image, describer.width() > 0);
    deduplicate_and_order(&mut candidates, &records, layers);
    let selected = select(&candidates, options, width, height);
    let keypoints: Vec<Keypoint> = selected.iter().map(|&i| candidates[i].keypoint).collect();
    let descriptor_width = describer.width();
    let mut descriptors = vec![D::Elem::default(); selected.len() * descriptor_width];
    if descriptor_width == 0 || selected.is_empty() {
        return Ok((keypoints, descriptors));
    }
    let description = Description {
        space: &space,
        pool: &pool,
        records: &records,
        candidates: &candidates,
        describer,
    };
    description.describe(&selected, &mut descriptors);
    Ok((keypoints, descriptors))
}

/// What the detection pass reads in every octave and band.
struct Detection<'a> {
    space: &'a ScaleSpace,
    tests: ExtremumTests,
    mask: Option<&'a Mask<'a>>,
    options: &'a DetectorOptions,
    pool: &'a PlanePool,
}

impl Detection<'_> {
    /// Detects in every usable octave: each octave's record (with the Gaussian layers kept for
    /// description, when `keep_layers` and they fit in a quarter of the memory budget) and the
    /// candidates of all octaves, octave by octave and band by band.
    fn detect_octaves(
        &self,
        image: &GreyImage,
        keep_layers: bool,
    ) -> (Vec<OctaveRecord>, Vec<Candidate>) {
        // A quarter of the budget keeps finished bands' layers; detection bands get half (see
        // `ScaleSpace::bands`); the rest is headroom for the recomputation in the description
        // pass.
        let mut keep_budget = self.options.memory_budget / 4;
        let mut records: Vec<OctaveRecord> = Vec::new();
        let mut candidates: Vec<Candidate> = Vec::new();
        let mut octave = first_octave(image, self.options);
        while octave_is_usable(octave.base.width, octave.base.height) {
            let (w, h) = (octave.base.width, octave.base.height);
            let bands = self.space.bands(w, h);
            let keep = bands_to_keep(&bands, w, self.space.layers, keep_layers, &mut keep_budget);
            let (next_w, next_h) = (w / 2, h / 2);
            let slot = records.len();
            let per_band: Vec<BandResult> = bands
                .par_iter()
                .enumerate()
                .map(|(b, band)| self.detect_band(&octave, slot, b, band, keep[b]))
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
        (records, candidates)
    }

    /// Detection in band `b` of `octave` (record `slot`): its candidates, its rows of the next
    /// octave's base and, when `keep`, its Gaussian layers 1 ..= L + 1.
    fn detect_band(
        &self,
        octave: &Octave,
        slot: usize,
        b: usize,
        band: &Band,
        keep: bool,
    ) -> BandResult {
        let layers = self.space.layers;
        let (w, h) = (octave.base.width, octave.base.height);
        let (next_w, next_h) = (w / 2, h / 2);
        let mut stack = self.space.stack(&octave.base, band, layers + 3, self.pool);
        let last = !octave_is_usable(next_w, next_h);
        let found: Vec<Candidate> = find_extrema(&stack, band, h, last, &self.tests)
            .into_par_iter()
            .flat_map_iter(|e| self.candidates_of(e, octave, &stack, slot, b))
            .collect();
        let next = self.space.decimate_core(&stack, band, next_h);
        let kept = keep.then(|| stack.gauss.drain(1..=layers + 1).collect());
        stack.recycle(self.pool);
        BandResult {
            found,
            next_rows: next,
            kept,
        }
    }

    /// The candidates of extremum `e` of band `b`: one per orientation, none outside the mask.
    fn candidates_of(
        &self,
        e: Extremum,
        octave: &Octave,
        stack: &BandStack,
        slot: usize,
        b: usize,
    ) -> impl Iterator<Item = Candidate> {
        let space = self.space;
        let step = octave.step();
        let x = e.x * step + 0.5;
        let y = e.y * step + 0.5;
        let allowed = self.mask.is_none_or(|m| m.allows(x, y));
        // Orientation and descriptor windows scale with the layer's σ (Lowe's convention);
        // `Keypoint::scale` reports the blob's σ, half a layer up (the DoG between two layers
        // peaks there).
        let sigma = space.layer_sigma(e.s);
        let layer = &stack.gauss[e.layer];
        let angles = match (allowed, self.options.orientation) {
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
        let octave_index = octave.index;
        angles.into_iter().map(move |angle| Candidate {
            keypoint: Keypoint {
                x,
                y,
                scale: space.layer_sigma(e.s + 0.5) * step,
                orientation: angle as f64,
                response: e.contrast as f32,
                octave: octave_index as i16,
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
    }
}

/// Which of an octave's bands (`width` columns) keep their Gaussian layers for description: in
/// band order, each whose layers fit in what is left of `keep_budget`, which it then takes.
fn bands_to_keep(
    bands: &[Band],
    width: usize,
    layers: usize,
    keep_layers: bool,
    keep_budget: &mut usize,
) -> Vec<bool> {
    bands
        .iter()
        .map(|band| {
            let bytes = (layers + 1) * width * band.rows.len() * std::mem::size_of::<f32>();
            let fits = keep_layers && bytes <= *keep_budget;
            if fits {
                *keep_budget -= bytes;
            }
            fits
        })
        .collect()
}

/// Removes the candidates found twice (refinement can lead two starting samples to the same
/// keypoint; two octaves can both keep a blob), then sorts them into one order whatever the
/// bands: a band also lists extrema that started beyond its core, so the order of discovery
/// depends on where bands begin.
fn deduplicate_and_order(candidates: &mut Vec<Candidate>, records: &[OctaveRecord], layers: usize) {
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
    drop_octave_duplicates(candidates, records, layers);
    candidates.sort_by(|a, b| {
        (a.octave, a.row, a.layer)
            .cmp(&(b.octave, b.row, b.layer))
            .then(a.x.total_cmp(&b.x))
            .then(a.y.total_cmp(&b.y))
            .then(a.s.total_cmp(&b.s))
            .then(a.keypoint.orientation.total_cmp(&b.keypoint.orientation))
    });
}

/// Indices of the candidates the keypoint budget keeps, in the order it took them (all of them,
/// in order, without a limit).
fn select(
    candidates: &[Candidate],
    options: &DetectorOptions,
    width: usize,
    height: usize,
) -> Vec<usize> {
    match options.limit {
        Some(limit) => {
            let points: Vec<(f64, f64, f32)> = candidates
                .iter()
                .map(|c| (c.keypoint.x, c.keypoint.y, c.keypoint.response))
                .collect();
            select_spread(&points, width, height, limit.max, limit.cells, limit.spread)
        }
        None => (0..candidates.len()).collect(),
    }
}

/// What the description pass reads: the detection's records and candidates, and how to
/// recompute the Gaussian layers that were not kept.
struct Description<'a, D: Describer> {
    space: &'a ScaleSpace,
    pool: &'a PlanePool,
    records: &'a [OctaveRecord],
    candidates: &'a [Candidate],
    describer: &'a D,
}

impl<D: Describer> Description<'_, D> {
    /// Writes the descriptor of every selected candidate into its slot of `descriptors`,
    /// describing band by band (each band's layers are at hand once).
    fn describe(&self, selected: &[usize], descriptors: &mut [D::Elem]) {
        let descriptor_width = self.describer.width();
        let mut groups: BTreeMap<(usize, usize), Vec<(usize, usize)>> = BTreeMap::new();
        for (slot, &i) in selected.iter().enumerate() {
            let c = &self.candidates[i];
            groups
                .entry((c.octave, c.band))
                .or_default()
                .push((slot, i));
        }
        let groups: Vec<BandMembers> = groups.into_iter().collect();
        let described: Vec<(Vec<usize>, Vec<D::Elem>)> = groups
            .par_iter()
            .map(|((o, b), members)| self.describe_band(*o, *b, members))
            .collect();
        for (slots, values) in described {
            for (slot, value) in slots.iter().zip(values.chunks(descriptor_width)) {
                descriptors[slot * descriptor_width..(slot + 1) * descriptor_width]
                    .copy_from_slice(value);
            }
        }
    }

    /// The output slots of `members` (of band `b` of octave record `o`) and their descriptors,
    /// from the band's kept Gaussian layers or layers recomputed for it.
    fn describe_band(
        &self,
        o: usize,
        b: usize,
        members: &[(usize, usize)],
    ) -> (Vec<usize>, Vec<D::Elem>) {
        let descriptor_width = self.describer.width();
        let record = &self.records[o];
        let band = &record.bands[b];
        let recomputed;
        let layer_planes: &[Plane] = match &record.kept[b] {
            Some(planes) => planes,
            None => {
                let mut stack =
                    self.space
                        .stack(&record.octave.base, band, self.space.layers + 1, self.pool);
                recomputed = stack.gauss.drain(1..).collect::<Vec<_>>();
                stack.recycle(self.pool);
                &recomputed
            }
        };
        let row0 = band.rows.start as f64;
        let mut out = vec![D::Elem::default(); members.len() * descriptor_width];
        out.par_chunks_mut(descriptor_width)
            .zip(members.par_iter())
            .for_each(|(dst, &(_, i))| {
                let c = &self.candidates[i];
                let local = LocalKeypoint {
                    x: c.x,
                    y: c.y - row0,
                    sigma: c.sigma as f32,
                    angle: c.keypoint.orientation as f32,
                };
                self.describer
                    .describe(&layer_planes[c.layer - 1], &local, dst);
            });
        (members.iter().map(|m| m.0).collect(), out)
    }
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
