//! The real-texture part of `cargo xtask bench dense`: `../shared/data/rendered-mar`, two real
//! beach surveys (sandpyper orthophotos and DSMs) rendered with exact truth, where synthetic
//! textures cannot flatter the matcher. The align stage orients the project; the dense stage
//! then runs on the true cameras and on the align stage's (timed as a process of its own, like
//! the synthetic scenes), and OpenCV's SGBM on the same images and cameras. Every cloud is
//! gridded the same way (the median height of its points in 0.6 m cells) and compared with the
//! epoch's true surface: the DEM's median error and NMAD over the cells it fills, and its
//! completeness over the cells that can be matched (a true height, seen by at least two of the
//! epoch's true cameras). Every cloud is also gridded as the DEM stage grids it (its default
//! `[raster]`: the median per cell, holes of up to `max_gap` cells interpolated) and scored the
//! same way: that is the DEM a user gets. A fused cloud has about one point per depth-map
//! pixel, laid on each view's rotated pixel lattice, so a lattice of that spacing leaves single
//! cells empty between points (moiré, not missing ground); SGBM's cloud, a point per pixel of
//! every pair, fills them by redundancy.

use std::path::Path;

use anyhow::Context;
use nalgebra::Vector3;
use rayon::prelude::*;
use timesift::Project;
use timesift::stages::{Stage, run};
use timesift_change::grid::Dem;
use timesift_core::{CameraModel, project_world};
use timesift_io::cameras_json::{Reconstruction, read_cameras_json};

use crate::bench_dense_time::{DenseBinary, DenseRun, time_dense};

/// The DEM cell the clouds are gridded at, m (about twice the finer epoch's GSD: one depth-map
/// pixel at level 2).
pub const CELL_M: f64 = 0.6;

/// One cloud's DEM against the truth.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct DemScore {
    /// Cells that can be matched (a true height, seen by two true cameras).
    pub matchable: usize,
    /// Of those, cells with at least one point.
    pub filled: usize,
    pub completeness: f64,
    /// Completeness on the lattice of the level's depth-map pixels ([`level_cell`]).
    pub completeness_level: f64,
    /// Median and NMAD of (cell median − true height), m.
    pub median_m: f64,
    pub nmad_m: f64,
    /// The same cloud gridded by the DEM stage (its default `[raster]`) on the same lattice.
    pub dem_stage: StageScore,
}

/// A cloud's DEM as the DEM stage makes it, against the truth over the matchable cells.
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct StageScore {
    /// Matchable cells with a height, measured or interpolated.
    pub completeness: f64,
    /// Of those, the share interpolated across a hole.
    pub interpolated: f64,
    /// Median and NMAD of (DEM − true height) over them, m.
    pub median_m: f64,
    pub nmad_m: f64,
    /// Matchable cells left without a height, by how many true cameras see them: two, three,
    /// four or more (a block's edges against its inside).
    pub holes_by_views: [usize; 3],
}

/// One epoch's scores: timesift and SGBM, on the true and on the align stage's cameras.
#[derive(Debug, Clone, serde::Serialize)]
struct EpochRow {
    epoch: String,
    truth: Option<DemScore>,
    truth_sgbm: Option<DemScore>,
    truth_before: Option<DemScore>,
    truth_openmvs: Option<DemScore>,
    align: Option<DemScore>,
    align_sgbm: Option<DemScore>,
}

/// What to run.
pub struct MarBench<'a> {
    pub out: &'a Path,
    pub level: u32,
    pub peer: bool,
    pub reuse: bool,
    pub baseline: Option<&'a Path>,
    pub openmvs: Option<&'a Path>,
}

/// Runs the bench; the markdown section and its JSON.
pub fn run_bench(bench: &MarBench) -> anyhow::Result<(String, serde_json::Value)> {
    let source = crate::shared_data().join("rendered-mar");
    let dir = bench.out.join("rendered-mar");
    let align_cameras = dir.join("cameras-align.json");
    let reused = bench.reuse && align_cameras.is_file();
    if !reused {
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).with_context(|| dir.display().to_string())?;
        crate::bench_coreg::copy_project(&source, &dir)?;
        crate::bench_dense::set_level(&dir, bench.level)?;
    }
    let project = Project::load(&dir)?;
    let layout = project.layout();
    if !reused {
        run(&project, Some(Stage::Features), Some(Stage::Align))?;
        std::fs::copy(layout.cameras_json(), &align_cameras)?;
    }
    let truth_cameras = read_cameras_json(&source.join("truth/cameras.json"))?;
    let truth_dems = project
        .epochs
        .iter()
        .map(|e| {
            let path = source.join(format!("truth/dem_{}.tif", e.name));
            Dem::from_raster(timesift_io::geotiff::read_f32(&path)?, None)
                .with_context(|| path.display().to_string())
        })
        .collect::<anyhow::Result<Vec<Dem>>>()?;
    let cells: Vec<(MatchableCells, MatchableCells)> = project
        .epochs
        .iter()
        .zip(&truth_dems)
        .map(|(e, dem)| {
            let at = |cell| MatchableCells::new(dem, &truth_cameras, &e.name, cell);
            (at(CELL_M), at(level_cell(&e.name, bench.level)))
        })
        .collect();
    let score_all = |clouds: &[Vec<Vector3<f64>>]| -> Vec<Option<DemScore>> {
        (0..project.epochs.len())
            .map(|e| {
                let cloud = clouds.get(e)?;
                Some(score_both(&cells[e], cloud, &truth_dems[e]))
            })
            .collect()
    };
    let none = || vec![None; project.epochs.len()];
    let mut runs: Vec<(String, DenseRun)> = Vec::new();
    let (mut truth, mut truth_sgbm, mut truth_before) = (none(), none(), none());
    let mut truth_openmvs = none();
    let (mut align, mut align_sgbm) = (none(), none());
    for cameras in ["true", "align"] {
        let from = match cameras {
            "true" => source.join("truth/cameras.json"),
            _ => align_cameras.clone(),
        };
        std::fs::copy(&from, layout.cameras_json())?;
        if cameras == "true" {
            if let Some(baseline) = bench.baseline {
                let run = time_dense(&DenseBinary::Timesift(baseline.to_path_buf()), &dir, 2)?;
                println!("rendered-mar: baseline, true cameras: {run:?}");
                runs.push(("baseline, true cameras".into(), run));
                truth_before = score_all(&crate::bench_dense::epoch_clouds(&project)?);
            }
            if let Some(bin) = bench.openmvs {
                let work = bench.out.join("rendered-mar-openmvs");
                match crate::bench_dense_openmvs::run_openmvs(&project, bench.level, bin, &work, 2)
                {
                    Ok(result) => {
                        println!("rendered-mar: OpenMVS, true cameras: {:?}", result.run);
                        runs.push(("OpenMVS, true cameras".into(), result.run));
                        truth_openmvs = score_all(&result.points);
                    }
                    Err(e) => println!("rendered-mar: OpenMVS not run: {e:#}"),
                }
            }
        }
        let run = time_dense(&DenseBinary::This, &dir, 2)?;
        println!("rendered-mar: this build, {cameras} cameras: {run:?}");
        runs.push((format!("this build, {cameras} cameras"), run));
        let scores = score_all(&crate::bench_dense::epoch_clouds(&project)?);
        let peer = if bench.peer {
            match crate::bench_dense_peer::run_sgbm(
                &project,
                bench.level,
                &bench.out.join(format!("rendered-mar-sgbm-{cameras}")),
            ) {
                Ok(result) => score_all(&result.points),
                Err(e) => {
                    println!("rendered-mar: OpenCV SGBM not run: {e:#}");
                    none()
                }
            }
        } else {
            none()
        };
        match cameras {
            "true" => (truth, truth_sgbm) = (scores, peer),
            _ => (align, align_sgbm) = (scores, peer),
        }
    }
    std::fs::copy(&align_cameras, layout.cameras_json())?;
    let report: timesift::report::DenseReport =
        timesift::report::read_json(&layout.dense_report())?;
    let megapixels = crate::bench_dense::depth_map_megapixels(&project, &report, bench.level)?;
    let rows: Vec<EpochRow> = project
        .epochs
        .iter()
        .enumerate()
        .map(|(e, epoch)| EpochRow {
            epoch: epoch.name.clone(),
            truth: truth[e],
            truth_sgbm: truth_sgbm[e],
            truth_before: truth_before[e],
            truth_openmvs: truth_openmvs[e],
            align: align[e],
            align_sgbm: align_sgbm[e],
        })
        .collect();
    let text = table(&rows, &runs, megapixels, bench.level);
    let json = serde_json::json!({
        "cell_m": CELL_M,
        "rows": rows,
        "runs": runs,
        "depth_map_megapixels": megapixels,
    });
    Ok((text, json))
}

/// Each epoch's DEM score of the dense clouds a rendered-mar project holds now (or, with
/// `sgbm`, of OpenCV's SGBM run on its cameras at its `[dense] level`), one line each.
pub fn score_project(dir: &Path, sgbm: bool) -> anyhow::Result<String> {
    let source = crate::shared_data().join("rendered-mar");
    let project = Project::load(dir)?;
    let cameras = read_cameras_json(&source.join("truth/cameras.json"))?;
    let clouds = match sgbm {
        true => {
            let work = dir.with_file_name(format!(
                "{}-sgbm",
                dir.file_name()
                    .map_or("project".into(), |n| n.to_string_lossy())
            ));
            let level = project.config.dense.level;
            crate::bench_dense_peer::run_sgbm(&project, level, &work)?.points
        }
        false => crate::bench_dense::epoch_clouds(&project)?,
    };
    let mut text = String::new();
    for (epoch, cloud) in project.epochs.iter().zip(&clouds) {
        let path = source.join(format!("truth/dem_{}.tif", epoch.name));
        let truth = Dem::from_raster(timesift_io::geotiff::read_f32(&path)?, None)?;
        let level = project.config.dense.level;
        let at = |cell| MatchableCells::new(&truth, &cameras, &epoch.name, cell);
        let cells = (at(CELL_M), at(level_cell(&epoch.name, level)));
        let s = score_both(&cells, cloud, &truth);
        text.push_str(&format!(
            "{}: {} points, median {:.3} m, NMAD {:.3} m, complete {:.3} ({} of {} cells), at {:.2} m {:.3}; \
             DEM stage: median {:.3} m, NMAD {:.3} m, complete {:.3} ({:.3} interpolated; \
             holes seen by 2 / 3 / 4+ true cameras: {:?})\n",
            epoch.name,
            cloud.len(),
            s.median_m,
            s.nmad_m,
            s.completeness,
            s.filled,
            s.matchable,
            level_cell(&epoch.name, level),
            s.completeness_level,
            s.dem_stage.median_m,
            s.dem_stage.nmad_m,
            s.dem_stage.completeness,
            s.dem_stage.interpolated,
            s.dem_stage.holes_by_views,
        ));
    }
    Ok(text)
}

/// A cloud scored on the 0.6 m lattice, with its completeness on the level's too.
fn score_both(
    (fine, level): &(MatchableCells, MatchableCells),
    cloud: &[Vector3<f64>],
    truth: &Dem,
) -> DemScore {
    DemScore {
        completeness_level: level.score(cloud, truth).completeness,
        ..fine.score(cloud, truth)
    }
}

/// The cells of an epoch's 0.6 m lattice (over its true DEM's extent) that can be matched: a
/// true height there, seen by at least two of the epoch's true cameras.
struct MatchableCells {
    cell: f64,
    x0: f64,
    y1: f64,
    width: usize,
    height: usize,
    /// True cameras that see each cell (0 where it has no true height).
    seen: Vec<u16>,
}

impl MatchableCells {
    fn new(truth: &Dem, cameras: &Reconstruction, epoch: &str, cell: f64) -> MatchableCells {
        let (x0, y0, x1, y1) = truth.grid.extent();
        let width = ((x1 - x0) / cell).floor() as usize;
        let height = ((y1 - y0) / cell).floor() as usize;
        let views: Vec<_> = cameras
            .images
            .iter()
            .filter(|im| im.epoch == epoch)
            .filter_map(|im| Some((cameras.cameras.get(&im.camera)?, im.pose?)))
            .collect();
        let seen: Vec<u16> = (0..width * height)
            .into_par_iter()
            .map(|k| {
                let (x, y) = cell_centre(x0, y1, cell, k % width, k / width);
                let z = truth.bilinear(x, y);
                if !z.is_finite() {
                    return 0;
                }
                let point = Vector3::new(x, y, z);
                let seen = views
                    .iter()
                    .filter(|(camera, pose)| {
                        pose.transform_point(&point).z > 0.0
                            && project_world(*camera, pose, &point).is_ok_and(|p| {
                                p.x >= 0.0
                                    && p.y >= 0.0
                                    && p.x < camera.width() as f64
                                    && p.y < camera.height() as f64
                            })
                    })
                    .count();
                seen.min(u16::MAX as usize) as u16
            })
            .collect();
        MatchableCells {
            cell,
            x0,
            y1,
            width,
            height,
            seen,
        }
    }

    /// Whether cell `k` can be matched: a true height, seen by two true cameras or more.
    fn is_matchable(&self, k: usize) -> bool {
        self.seen[k] >= 2
    }

    /// The cloud gridded (median height per cell) and compared with the truth.
    fn score(&self, cloud: &[Vector3<f64>], truth: &Dem) -> DemScore {
        let mut keyed: Vec<(usize, f64)> = cloud
            .iter()
            .filter_map(|p| {
                let c = (p.x - self.x0) / self.cell;
                let r = (self.y1 - p.y) / self.cell;
                let inside =
                    c >= 0.0 && r >= 0.0 && c < self.width as f64 && r < self.height as f64;
                inside.then(|| (r as usize * self.width + c as usize, p.z))
            })
            .collect();
        keyed.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
        let mut errors = Vec::new();
        let mut filled = 0;
        for run in keyed.chunk_by(|a, b| a.0 == b.0) {
            let k = run[0].0;
            if !self.is_matchable(k) {
                continue;
            }
            filled += 1;
            let n = run.len();
            let median = match n % 2 {
                1 => run[n / 2].1,
                _ => 0.5 * (run[n / 2 - 1].1 + run[n / 2].1),
            };
            let (x, y) = cell_centre(self.x0, self.y1, self.cell, k % self.width, k / self.width);
            errors.push(median - truth.bilinear(x, y));
        }
        let matchable = (0..self.seen.len())
            .filter(|&k| self.is_matchable(k))
            .count();
        let stats = timesift_change::stats::statistics(errors);
        DemScore {
            matchable,
            filled,
            completeness: filled as f64 / matchable.max(1) as f64,
            completeness_level: f64::NAN,
            median_m: stats.as_ref().map_or(f64::NAN, |s| s.median),
            nmad_m: stats.as_ref().map_or(f64::NAN, |s| s.nmad),
            dem_stage: self.score_dem_stage(cloud, truth, matchable),
        }
    }

    /// The cloud gridded on this lattice by the DEM stage's gridding with the default
    /// `[raster]` options, scored over the `matchable` cells.
    fn score_dem_stage(&self, cloud: &[Vector3<f64>], truth: &Dem, matchable: usize) -> StageScore {
        let options = timesift::config::RasterConfig::default().dem_options(self.cell);
        let points: Vec<[f64; 3]> = cloud.iter().map(|p| [p.x, p.y, p.z]).collect();
        let dem =
            timesift_raster::Lattice::new(self.x0, self.y1, self.cell, self.width, self.height)
                .and_then(|lattice| timesift_raster::grid_cloud(&points, &lattice, &options));
        let Ok(dem) = dem else {
            return StageScore {
                completeness: f64::NAN,
                interpolated: f64::NAN,
                median_m: f64::NAN,
                nmad_m: f64::NAN,
                holes_by_views: [0; 3],
            };
        };
        let (mut errors, mut interpolated) = (Vec::new(), 0usize);
        let mut holes_by_views = [0; 3];
        for k in (0..self.seen.len()).filter(|&k| self.is_matchable(k)) {
            let h = dem.height[k];
            if !h.is_finite() {
                holes_by_views[(self.seen[k] as usize).clamp(2, 4) - 2] += 1;
                continue;
            }
            interpolated += usize::from(dem.filled[k]);
            let (x, y) = cell_centre(self.x0, self.y1, self.cell, k % self.width, k / self.width);
            errors.push(h as f64 - truth.bilinear(x, y));
        }
        let with_height = errors.len();
        let stats = timesift_change::stats::statistics(errors);
        StageScore {
            completeness: with_height as f64 / matchable.max(1) as f64,
            interpolated: interpolated as f64 / with_height.max(1) as f64,
            median_m: stats.as_ref().map_or(f64::NAN, |s| s.median),
            nmad_m: stats.as_ref().map_or(f64::NAN, |s| s.nmad),
            holes_by_views,
        }
    }
}

fn cell_centre(x0: f64, y1: f64, cell: f64, col: usize, row: usize) -> (f64, f64) {
    (
        x0 + (col as f64 + 0.5) * cell,
        y1 - (row as f64 + 0.5) * cell,
    )
}

/// The lattice of the level's depth-map pixels on the ground (level × the epoch's GSD, at
/// least [`CELL_M`]): a cloud of the level can fill every cell of it, which at 0.6 m the
/// coarser epoch's (0.71 m spacing at level 2) cannot.
fn level_cell(epoch: &str, level: u32) -> f64 {
    let gsd = crate::bench_coreg::gsd_of(epoch);
    (level.max(1) as f64 * gsd).max(CELL_M)
}

/// A row per epoch and cameras: timesift's, SGBM's, the baseline's and OpenMVS's scores, each
/// shown by `cell`.
fn score_table(rows: &[EpochRow], cell: &dyn Fn(&Option<DemScore>) -> String) -> String {
    let mut text = String::from(
        "| epoch | cameras | timesift median | NMAD | complete | SGBM median | NMAD | complete | baseline median | NMAD | complete | OpenMVS median | NMAD | complete |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        text.push_str(&format!(
            "| {} | true | {} | {} | {} | {} |\n",
            r.epoch,
            cell(&r.truth),
            cell(&r.truth_sgbm),
            cell(&r.truth_before),
            cell(&r.truth_openmvs)
        ));
        text.push_str(&format!(
            "| {} | align | {} | {} | – | – | – | – | – | – |\n",
            r.epoch,
            cell(&r.align),
            cell(&r.align_sgbm)
        ));
    }
    text
}

/// Where the DEM-stage grids keep holes: by how many true cameras see the cell (two: a block's
/// edges).
fn holes_table(rows: &[EpochRow]) -> String {
    let holes = |s: &Option<DemScore>| {
        s.map_or("–".to_string(), |s| {
            let [two, three, more] = s.dem_stage.holes_by_views;
            format!("{two} / {three} / {more}")
        })
    };
    let mut text = String::from(
        "\nHoles of those DEMs (matchable cells without a height), by how many true cameras see \
         the cell: 2 / 3 / 4 or more.\n\n| epoch | cameras | timesift | SGBM | baseline | OpenMVS |\n\
         |---|---|---|---|---|---|\n",
    );
    for r in rows {
        for (cameras, [ours, sgbm, before, openmvs]) in [
            (
                "true",
                [&r.truth, &r.truth_sgbm, &r.truth_before, &r.truth_openmvs],
            ),
            ("align", [&r.align, &r.align_sgbm, &None, &None]),
        ] {
            text.push_str(&format!(
                "| {} | {cameras} | {} | {} | {} | {} |\n",
                r.epoch,
                holes(ours),
                holes(sgbm),
                holes(before),
                holes(openmvs)
            ));
        }
    }
    text
}

fn table(rows: &[EpochRow], runs: &[(String, DenseRun)], megapixels: f64, level: u32) -> String {
    let figures = |[median, nmad, complete, bracket]: [f64; 4]| {
        format!("{median:.3} | {nmad:.3} | {complete:.3} ({bracket:.3})")
    };
    let cell = |s: &Option<DemScore>| {
        s.map_or("– | – | –".to_string(), |s| {
            figures([s.median_m, s.nmad_m, s.completeness, s.completeness_level])
        })
    };
    let stage = |s: &Option<DemScore>| {
        s.map_or("– | – | –".to_string(), |s| {
            let d = s.dem_stage;
            figures([d.median_m, d.nmad_m, d.completeness, d.interpolated])
        })
    };
    let mut text = format!(
        "\n## rendered-mar (real beach texture, level {level}; clouds gridded at {CELL_M} m, \
         median / NMAD (m) / completeness against the true DEM; in brackets the completeness on the \
         lattice of the level's depth-map pixels, level × GSD)\n\n{}",
        score_table(rows, &cell)
    );
    text.push_str(&format!(
        "\nThe same clouds gridded as the DEM stage grids them (default `[raster]`: the median per \
         {CELL_M} m cell, holes of up to {} cells interpolated): the DEM a user gets. Median / NMAD \
         (m) / completeness; in brackets the share of its heights interpolated.\n\n{}",
        timesift::config::RasterConfig::default().max_gap,
        score_table(rows, &stage)
    ));
    text.push_str(&holes_table(rows));
    text.push_str(&format!(
        "\nDense stage, 2 threads, {megapixels:.2} depth-map MP:\n\n\
         | run | wall s | CPU s | core-s/MP | peak MiB |\n|---|---|---|---|---|\n"
    ));
    for (name, run) in runs {
        text.push_str(&format!(
            "| {name} | {:.1} | {:.1} | {:.1} | {:.0} |\n",
            run.wall,
            run.cpu,
            run.cpu / megapixels,
            run.peak_mib
        ));
    }
    text
}
