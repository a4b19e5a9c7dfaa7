//! The cluster plan: every step of every stage with its units, the memory one unit needs and
//! the files the step writes, worked out from `project.toml`, the image list, the priors and
//! the images' headers only, so that it can be printed (`--dry-run`) and submitted before any
//! stage has run.
//!
//! Memory per unit is an estimate from the options and the images' sizes; each step's formula is
//! in [`Step::memory_formula`] and printed in its batch script, so nobody guesses and anybody
//! can check it against `sacct`'s MaxRSS.

use std::collections::BTreeSet;

use crate::config::PairSelection;
use crate::stages::Stage;
use crate::{Project, ProjectError};

/// How finely the parallel steps are split (the `[cluster]` keys of the same names).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanOptions {
    /// CPUs each task gets (Slurm's `--cpus-per-task`); the unit's threads.
    pub cpus_per_task: usize,
    /// Images per unit of `features`.
    pub images_per_task: usize,
    /// Pairs per unit of `match`.
    pub pairs_per_task: usize,
    /// Reference images per unit of each dense pass.
    pub views_per_task: usize,
    /// Ortho cells per unit of `ortho`, millions.
    pub ortho_megapixels_per_task: f64,
}

impl Default for PlanOptions {
    fn default() -> Self {
        PlanOptions {
            cpus_per_task: 4,
            images_per_task: 40,
            pairs_per_task: 2000,
            views_per_task: 8,
            ortho_megapixels_per_task: 100.0,
        }
    }
}

/// One step of the plan.
#[derive(Debug, Clone, PartialEq)]
pub struct Step {
    /// Its name (`timesift task <name>`).
    pub name: String,
    /// The stage it belongs to.
    pub stage: Stage,
    /// Its independent units.
    pub units: usize,
    /// What a unit is, for people.
    pub unit: String,
    /// Memory one unit needs, MiB.
    pub memory_mib: u64,
    /// How that was worked out.
    pub memory_formula: String,
    /// Files the whole step writes (an upper bound where the pairs are preselected later).
    pub files: u64,
}

/// The sizes of the images, per epoch, from one image's header each.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageSizes {
    /// Width and height of each epoch's images.
    pub per_epoch: Vec<(u32, u32)>,
    /// Epochs whose size was assumed (no readable image).
    pub assumed: Vec<String>,
}

/// The size assumed for an epoch none of whose images could be read (a 24-megapixel frame).
const ASSUMED_SIZE: (u32, u32) = (6000, 4000);

impl ImageSizes {
    /// Reads the header of the first image of each epoch.
    pub fn of(project: &Project) -> ImageSizes {
        let mut assumed = Vec::new();
        let per_epoch = project
            .epochs
            .iter()
            .map(|epoch| {
                let first = epoch.images.first().map(|i| &project.images[i.index()]);
                first
                    .and_then(|im| image::image_dimensions(project.dir.join(&im.name)).ok())
                    .unwrap_or_else(|| {
                        assumed.push(epoch.name.clone());
                        ASSUMED_SIZE
                    })
            })
            .collect();
        ImageSizes { per_epoch, assumed }
    }
}

/// The plan of a whole run.
#[derive(Debug, Clone, PartialEq)]
pub struct ClusterPlan {
    /// The steps, in order.
    pub steps: Vec<Step>,
    /// What the plan assumed.
    pub notes: Vec<String>,
}

/// Keypoints per pixel the detector finds before `max_keypoints` caps it: the 800-image scale
/// bench's 480 x 360 images gave about 10,000 each (1.6 MB feature files).
const KEYPOINTS_PER_PIXEL: f64 = 0.06;
/// Fused points per working-image pixel: 6,936,432 points from 800 images of 240 x 180 working
/// pixels on the 800-image scale bench.
const POINTS_PER_WORKING_PIXEL: f64 = 0.2;

/// Ortho cells per fused point: a DEM cell per point, and the default ortho lattice's 2 × 2
/// cells per DEM cell.
const ORTHO_CELLS_PER_POINT: f64 = 4.0;

const MIB: f64 = 1024.0 * 1024.0;
/// What any unit needs besides its data: the binary, the project, buffers.
const BASE_MIB: u64 = 512;
/// Bytes per keypoint in memory with its 128-byte descriptor.
const FEATURE_BYTES: f64 = 160.0;

fn mib(bytes: f64) -> u64 {
    BASE_MIB + (bytes / MIB).ceil() as u64
}

fn step(
    name: impl Into<String>,
    stage: Stage,
    units: usize,
    unit: impl Into<String>,
    bytes: f64,
    formula: impl Into<String>,
    files: u64,
) -> Step {
    Step {
        name: name.into(),
        stage,
        units: units.max(1),
        unit: unit.into(),
        memory_mib: mib(bytes),
        memory_formula: format!("512 MiB + {}", formula.into()),
        files,
    }
}

/// The number of dense passes an epoch whose images are `size` runs with the project's
/// `[dense]` options (as the dense stage will schedule them).
pub(crate) fn dense_passes(project: &Project, epoch: usize, size: (u32, u32)) -> usize {
    let options = project.config.dense.options(project.image_kind(epoch));
    let refined = usize::from(options.plan.refine && options.plan.level > 1);
    let level = (options.plan.level >> refined).max(1) as usize;
    // The working images are undistorted and may be larger than the photographs (barrel
    // distortion's periphery kept): planned for half as large again, since a pass step more
    // than the epoch needs costs nothing (its units find no pass) and one too few would leave
    // the finest maps to the fusion unit.
    let side = size.0.max(size.1) as usize * 3 / 2 / level;
    timesift_dense::schedule(side, refined, &options.patchmatch).len()
}

/// The plan of every stage of the project, with `options`' split.
pub fn cluster_plan(project: &Project, options: &PlanOptions) -> Result<ClusterPlan, ProjectError> {
    let sizes = ImageSizes::of(project);
    let n = project.images.len();
    let cpus = options.cpus_per_task.max(1) as f64;
    let largest_px = sizes
        .per_epoch
        .iter()
        .map(|&(w, h)| w as f64 * h as f64)
        .fold(0.0, f64::max);
    let keypoints =
        (largest_px * KEYPOINTS_PER_PIXEL).min(project.config.align.max_keypoints as f64);
    let mut steps = Vec::new();

    // features
    steps.push(step(
        "features-prepare",
        Stage::Features,
        1,
        "the settings, and the scans' fiducial marks",
        largest_px * 16.0,
        "16 B per pixel of the largest image",
        2,
    ));
    let per = options.images_per_task.max(1);
    steps.push(step(
        "features",
        Stage::Features,
        n.div_ceil(per),
        format!("{per} images"),
        cpus * largest_px * 64.0,
        format!("{cpus} CPUs x 64 B per pixel of the largest image (its scale space)"),
        n as u64,
    ));

    // match
    let epoch_of: Vec<_> = project.images.iter().map(|im| im.epoch).collect();
    let candidates = crate::stages::candidate_pairs(project, &epoch_of)?;
    let preselect = project.config.align.pair_selection == PairSelection::Preselect;
    steps.push(step(
        "match-prepare",
        Stage::Match,
        1,
        "the pairs to match",
        if preselect {
            n as f64 * keypoints * FEATURE_BYTES
        } else {
            candidates.len() as f64 * 64.0
        },
        if preselect {
            "every image's features (preselection)"
        } else {
            "the candidate pairs"
        },
        2,
    ));
    let per = options.pairs_per_task.max(1);
    let units = candidates.len().div_ceil(per).max(1);
    let mut most_images = 0;
    for index in 1..=units {
        let part = super::Part {
            index,
            count: units,
        };
        let images: BTreeSet<usize> = candidates[part.range(candidates.len())]
            .iter()
            .flat_map(|&(a, b)| [a, b])
            .collect();
        most_images = most_images.max(images.len());
    }
    steps.push(step(
        "match",
        Stage::Match,
        units,
        format!("{per} pairs"),
        most_images as f64 * keypoints * FEATURE_BYTES,
        format!("the features of the most images a unit's pairs touch ({most_images})"),
        candidates.len() as u64,
    ));
    steps.push(step(
        "match-tracks",
        Stage::Match,
        1,
        "the tracks over every verified pair",
        n as f64 * keypoints * 48.0 + candidates.len() as f64 * 30_000.0,
        "48 B per keypoint and 30 kB per pair's matches",
        1,
    ));

    // align: one task, the whole block. Measured: 6.0 GiB peak on the 800-image scale bench.
    steps.push(step(
        "align",
        Stage::Align,
        1,
        "the whole block",
        n as f64 * keypoints * 800.0,
        format!(
            "800 B per keypoint, {keypoints:.0} per image (the 800-image scale bench: 6.0 GiB \
             for 10,000 per image)"
        ),
        5 + n as u64,
    ));

    // dense
    let epochs = project.epochs.len();
    let options_of = |e: usize| project.config.dense.options(project.image_kind(e));
    let working_px = |e: usize| {
        let o = options_of(e);
        let refined = u32::from(o.plan.refine && o.plan.level > 1);
        let level = (o.plan.level >> refined).max(1) as f64;
        let (w, h) = sizes.per_epoch[e];
        w as f64 * h as f64 / (level * level)
    };
    let largest_working = (0..epochs).map(working_px).fold(0.0, f64::max);
    let sources = (0..epochs)
        .map(|e| options_of(e).plan.max_sources)
        .max()
        .unwrap_or(8) as f64;
    steps.push(step(
        "dense-prepare",
        Stage::Dense,
        1,
        "each epoch's plan of sources",
        n as f64 * 4096.0,
        "4 KiB per image",
        epochs as u64,
    ));
    let passes = (0..epochs)
        .map(|e| dense_passes(project, e, sizes.per_epoch[e]))
        .max()
        .unwrap_or(0);
    let per = options.views_per_task.max(1);
    let map_cache = 384.0 * MIB;
    for k in 0..passes {
        steps.push(step(
            format!("dense-pass-{k}"),
            Stage::Dense,
            n.div_ceil(per),
            format!("{per} reference images"),
            map_cache + (2.0 * (sources + 1.0) * 20.0 + (sources + 1.0) * 32.0) * largest_working,
            format!(
                "384 MiB of maps + {} working images of 20 B and {} maps of 32 B per pixel \
                 ({:.1} MP)",
                2.0 * (sources + 1.0),
                sources + 1.0,
                largest_working / 1e6
            ),
            n as u64,
        ));
    }
    // Each epoch's fused cloud, points; the largest's.
    let epoch_points: Vec<f64> = project
        .epochs
        .iter()
        .enumerate()
        .map(|(e, ep)| ep.images.len() as f64 * working_px(e) * POINTS_PER_WORKING_PIXEL)
        .collect();
    let largest_epoch = epoch_points.iter().copied().fold(0.0, f64::max);
    steps.push(step(
        "dense-fuse",
        Stage::Dense,
        epochs,
        "one epoch's filtering and fusion",
        map_cache + largest_epoch * 100.0,
        format!(
            "384 MiB of maps + 100 B per point of the largest epoch's cloud ({:.1} million: \
             0.2 per working pixel)",
            largest_epoch / 1e6
        ),
        (n + 2 * epochs) as u64,
    ));
    steps.push(step(
        "dense-report",
        Stage::Dense,
        1,
        "out/dense.json",
        0.0,
        "nothing else",
        1,
    ));
    // The raster stages: one lattice, then an epoch per unit.
    steps.push(step(
        "dem-grid",
        Stage::Dem,
        1,
        "the project's lattice from every epoch's cloud",
        largest_epoch * 24.0,
        "24 B per point of the largest epoch's cloud (its positions)",
        1,
    ));
    steps.push(step(
        "dem",
        Stage::Dem,
        epochs,
        "one epoch's DEM",
        largest_epoch * 48.0,
        "48 B per point of the largest epoch's cloud (its positions and the grids)",
        6 * epochs as u64,
    ));
    // Every epoch's mosaic: its gains (a fit over every tile), its rows of tiles shared out
    // among the units, then one merge per epoch. An ortho cell per DEM cell and a DEM cell per
    // fused point, at the default lattices' factor of 2 per side: 4 cells per point.
    let ortho_cells: f64 = ORTHO_CELLS_PER_POINT * epoch_points.iter().sum::<f64>();
    let per_unit = options.ortho_megapixels_per_task.max(1e-6) * 1e6;
    let ortho_units = ((ortho_cells / per_unit).ceil() as usize).max(epochs);
    let dem_bytes = largest_epoch * 16.0;
    let cache = 1536.0 * MIB;
    steps.push(step(
        "ortho-gains",
        Stage::Ortho,
        epochs,
        "one epoch's exposure gains (every tile's overlaps)",
        dem_bytes + cache,
        "16 B per point of the largest epoch's cloud (its DEM) and the 1.5 GiB image cache",
        epochs as u64,
    ));
    let part_cells = (ortho_cells / ortho_units as f64).ceil();
    steps.push(step(
        "ortho",
        Stage::Ortho,
        ortho_units,
        format!(
            "rows of tiles of the epochs' orthomosaics ({:.0} million cells)",
            part_cells / 1e6
        ),
        dem_bytes + cache + 8.0 * part_cells,
        format!(
            "16 B per point of the largest epoch's cloud (its DEM), the 1.5 GiB image cache and \
             8 B per cell of its part ({:.1} million: 4 per fused point, shared out)",
            part_cells / 1e6
        ),
        2 * (ortho_units + epochs) as u64,
    ));
    let largest_part = part_cells.min(ORTHO_CELLS_PER_POINT * largest_epoch);
    steps.push(step(
        "ortho-merge",
        Stage::Ortho,
        epochs,
        "one epoch's orthomosaic from its parts",
        dem_bytes + 8.0 * largest_part,
        "16 B per point of the largest epoch's cloud (its DEM) and 8 B per cell of the largest \
         part",
        3 * epochs as u64,
    ));
    steps.push(step(
        "ortho-report",
        Stage::Ortho,
        1,
        "out/raster.json",
        0.0,
        "nothing else",
        1,
    ));
    let pairs = crate::stages::epoch_pairs(project).len();
    steps.push(step(
        "change",
        Stage::Change,
        pairs,
        "one epoch pair's change products",
        2.0 * largest_epoch * 64.0,
        "two epochs' clouds with their search trees, 64 B per point",
        8 * pairs as u64,
    ));
    steps.push(step(
        "report",
        Stage::Report,
        1,
        "report.json and report.html",
        512.0 * MIB,
        "512 MiB for the figures",
        2,
    ));
    let mut notes = Vec::new();
    if !sizes.assumed.is_empty() {
        notes.push(format!(
            "no readable image in epoch(s) {}: assumed {} x {} pixels",
            sizes.assumed.join(", "),
            ASSUMED_SIZE.0,
            ASSUMED_SIZE.1
        ));
    }
    if preselect {
        notes.push(
            "pairs are preselected by the match-prepare step: match units and files are the \
             candidates', an upper bound"
                .into(),
        );
    }
    Ok(ClusterPlan { steps, notes })
}

impl ClusterPlan {
    /// The steps of the stages `stages`, in order.
    pub fn of_stages(&self, stages: &[Stage]) -> Vec<&Step> {
        self.steps
            .iter()
            .filter(|s| stages.contains(&s.stage))
            .collect()
    }
}
