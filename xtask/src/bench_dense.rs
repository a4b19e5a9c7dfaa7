//! `cargo xtask bench dense`: the dense stage against the truth of the `synth` scenes, with the
//! true cameras and with the cameras of the `align` stage, beside OpenCV's semi-global matcher
//! on the same undistorted images and cameras; and on `lund` (real images, the align stage's
//! cameras), the reprojection of the fused points and a rendering of the cloud.
//!
//! Scores, per scene and epoch, on textured land (cells whose land cover has full texture
//! contrast — not snow, ice or water — and away from buildings and other blocks):
//! - accuracy: |height error| of the fused points against the true surface (the rendered
//!   heightfield; the wall's depth for `soil-pit`), median and 90th percentile, in ground
//!   sampling distances (GSD: median range of the images' central rays over the focal length);
//! - completeness: of the evaluation cells whose centre on the true surface is seen by at least
//!   three images (on the photograph: a film scan's dark edge, where its marks sit, sees
//!   nothing), the fraction holding a fused point. Fusion makes one point per working pixel
//!   of one image (each pixel joins one point), so a cell is 2 × 2 working pixels where the
//!   images see the ground coarsest (2 × level × the 90th percentile of the local GSD).
//!
//! Cost, per scene (true cameras), the dense stage run as a process of its own (`xtask
//! run-dense`) on 1 and 2 threads: wall and CPU seconds, peak resident memory, and
//! core-seconds per depth-map megapixel (CPU seconds over the megapixels of the depth maps at
//! the level, every image with sources); where the time went (`dense.json` phase_seconds). With
//! `--baseline <timesift>`, another build's dense stage runs on the same projects first, timed
//! and scored the same way: the before and after of one run. With `--reuse --keep-maps`, an
//! earlier run's depth maps are kept: `[dense]` filtering and fusion options edited in the
//! scenes' `project.toml` (and `<scene>-truth/`'s) redo only the clouds, in seconds.

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::bench_dense_time::{DenseBinary, DenseRun, resume_dense, time_dense};
use anyhow::Context;
use nalgebra::Vector3;
use rayon::prelude::*;
use timesift::Project;
use timesift::stages::{Stage, run};
use timesift_eval::true_scene::{TrueEpoch, focal, write_true_orientation};
use timesift_io::cameras_json::{Reconstruction, read_cameras_json};
use timesift_synth::render::Material;
use timesift_synth::scene::SceneSpec;

/// What to run.
pub struct DenseBench {
    pub scenes: Vec<String>,
    pub level: u32,
    pub seed: u64,
    pub out: PathBuf,
    pub peer: bool,
    pub lund: bool,
    /// Reuse a scene already rendered and oriented in the output folder, and skip the
    /// one-thread timing (for iterating on the dense stage).
    pub reuse: bool,
    /// Another build's `timesift`, run on the same projects (the before of the tables).
    pub baseline: Option<PathBuf>,
    /// Only the true cameras (no align-stage cameras).
    pub truth_only: bool,
    /// With `reuse`: keep the scenes' depth maps, so that a `[dense]` filtering or fusion
    /// option edited in their `project.toml` redoes only the clouds (the cost table then times
    /// that alone).
    pub keep_maps: bool,
    /// A folder with OpenMVS's `InterfaceCOLMAP` and `DensifyPointCloud`: the multi-view peer,
    /// run on the true cameras.
    pub openmvs: Option<PathBuf>,
}

/// Scores of one cloud of one epoch.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct Score {
    pub points: usize,
    pub evaluated: usize,
    pub median_gsd: f64,
    pub p90_gsd: f64,
    pub completeness: f64,
    pub cells: usize,
}

/// One row of the table.
#[derive(Debug, Clone, serde::Serialize)]
struct Row {
    scene: String,
    epoch: String,
    gsd_m: f64,
    truth: Score,
    align: Option<Score>,
    peer: Option<Score>,
    /// The baseline build's clouds (true, align-stage cameras).
    truth_before: Option<Score>,
    align_before: Option<Score>,
    /// OpenMVS on the true cameras.
    openmvs: Option<Score>,
}

/// The dense stage's cost on a scene (true cameras), this build's and the baseline's, and the
/// peer's seconds per image.
#[derive(Debug, Clone, Default, serde::Serialize)]
struct Timing {
    scene: String,
    images: usize,
    /// Megapixels of the depth maps at the level (every image with sources, all epochs).
    megapixels: f64,
    /// This build, 1 and 2 threads (1 thread skipped when reusing).
    runs: Vec<DenseRun>,
    /// The baseline build, the same runs.
    baseline_runs: Vec<DenseRun>,
    /// This build's phases on 2 threads, summed over the epochs (`out/dense.json`).
    phases: timesift::report::DensePhaseSeconds,
    peer_1: Option<f64>,
    peer_2: Option<f64>,
    /// OpenMVS's DensifyPointCloud, 2 threads, every epoch.
    openmvs: Option<DenseRun>,
}

pub fn run_bench(bench: &DenseBench) -> anyhow::Result<()> {
    std::fs::create_dir_all(&bench.out).with_context(|| bench.out.display().to_string())?;
    let mut rows = Vec::new();
    let mut timings = Vec::new();
    let mut mar = None;
    for scene in &bench.scenes {
        if scene == "rendered-mar" {
            mar = Some(crate::bench_dense_mar::run_bench(
                &crate::bench_dense_mar::MarBench {
                    out: &bench.out,
                    level: bench.level,
                    peer: bench.peer,
                    reuse: bench.reuse,
                    baseline: bench.baseline.as_deref(),
                    openmvs: bench.openmvs.as_deref(),
                },
            )?);
            continue;
        }
        let (r, t) = bench_scene(bench, scene)?;
        rows.extend(r);
        timings.push(t);
        let text = table(&rows, &timings, bench.level);
        std::fs::write(bench.out.join("dense.md"), &text)?;
    }
    let mut text = table(&rows, &timings, bench.level);
    if let Some((mar_text, _)) = &mar {
        text.push_str(mar_text);
    }
    if bench.lund {
        text.push_str(&crate::bench_dense_lund::run(&bench.out, bench.level)?);
    }
    crate::write_results(
        &bench.out,
        "dense",
        &text,
        &serde_json::json!({
            "rows": rows,
            "timings": timings,
            "rendered_mar": mar.map(|(_, json)| json),
        }),
    )
}

pub(crate) fn pool(threads: usize) -> anyhow::Result<rayon::ThreadPool> {
    Ok(rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?)
}

fn bench_scene(bench: &DenseBench, scene: &str) -> anyhow::Result<(Vec<Row>, Timing)> {
    let spec =
        timesift_synth::scenes::build(scene, timesift_synth::scenes::Scale::Small, bench.seed)?;
    let dir = bench.out.join(scene);
    // Without align-stage rows the scene is only rendered: the true cameras need no orientation.
    let prepared = match bench.truth_only {
        true => dir.join("project.toml"),
        false => dir.join("out/cameras.json"),
    };
    let reused = bench.reuse && prepared.is_file();
    if !reused {
        let _ = std::fs::remove_dir_all(&dir);
        timesift_synth::writer::write_scene(
            &spec,
            &dir,
            &timesift_synth::writer::WriteOptions::default(),
        )?;
        set_level(&dir, bench.level)?;
    }
    let project = Project::load(&dir)?;
    if !reused && !bench.truth_only {
        let start = Instant::now();
        run(&project, Some(Stage::Features), Some(Stage::Align))?;
        println!(
            "{scene}: oriented in {:.1} s",
            start.elapsed().as_secs_f64()
        );
    }
    // The true cameras, with sparse points on the true surface.
    let truth_dir = bench.out.join(format!("{scene}-truth"));
    let truth_project = if reused && truth_dir.join("out/cameras.json").is_file() {
        Project::load(&truth_dir)?
    } else {
        truth_copy(&spec, &dir, &truth_dir)?
    };
    let baseline = bench.baseline.clone().map(DenseBinary::Timesift);
    let threads: &[usize] = if bench.reuse { &[2] } else { &[1, 2] };
    let images = project.images.len();
    let mut timing = Timing {
        scene: scene.to_string(),
        images,
        ..Timing::default()
    };
    // Each build's last run (2 threads) leaves its clouds to score; the baseline's first.
    let mut before = Vec::new();
    if let Some(baseline) = &baseline {
        for &n in threads {
            let run = time_dense(baseline, &truth_dir, n)?;
            println!("{scene}: baseline, {n} thread(s): {run:?}");
            timing.baseline_runs.push(run);
        }
        before = epoch_clouds(&truth_project)?;
    }
    let this_run = |dir: &Path, n: usize| match bench.keep_maps && reused {
        true => resume_dense(&DenseBinary::This, dir, n),
        false => time_dense(&DenseBinary::This, dir, n),
    };
    for &n in threads {
        let run = this_run(&truth_dir, n)?;
        println!("{scene}: this build, {n} thread(s): {run:?}");
        timing.runs.push(run);
    }
    let report: timesift::report::DenseReport =
        timesift::report::read_json(&truth_project.layout().dense_report())?;
    timing.megapixels = depth_map_megapixels(&truth_project, &report, bench.level)?;
    for epoch in report.epochs.values() {
        timing.phases += &epoch.phase_seconds;
    }
    // The align stage's cameras.
    let mut align_before = Vec::new();
    if !bench.truth_only {
        if let Some(baseline) = &baseline {
            time_dense(baseline, &dir, 2)?;
            align_before = epoch_clouds(&project)?;
        }
        this_run(&dir, 2)?;
    }
    let truth_cameras = read_cameras_json(&truth_project.layout().truth_cameras())?;
    let mut peer_points: Vec<Option<Vec<Vector3<f64>>>> = vec![None; project.epochs.len()];
    if bench.peer {
        match crate::bench_dense_peer::run_sgbm(
            &truth_project,
            bench.level,
            &bench.out.join(format!("{scene}-sgbm")),
        ) {
            Ok(result) => {
                timing.peer_1 = Some(result.seconds_1 / images as f64);
                timing.peer_2 = Some(result.seconds_2 / images as f64);
                peer_points = result.points.into_iter().map(Some).collect();
            }
            Err(e) => println!("{scene}: OpenCV SGBM not run: {e:#}"),
        }
    }
    let mut openmvs_points: Vec<Option<Vec<Vector3<f64>>>> = vec![None; project.epochs.len()];
    if let Some(bin) = &bench.openmvs {
        let work = bench.out.join(format!("{scene}-openmvs"));
        match crate::bench_dense_openmvs::run_openmvs(&truth_project, bench.level, bin, &work, 2) {
            Ok(result) => {
                println!("{scene}: OpenMVS, 2 threads: {:?}", result.run);
                timing.openmvs = Some(result.run);
                openmvs_points = result.points.into_iter().map(Some).collect();
            }
            Err(e) => println!("{scene}: OpenMVS not run: {e:#}"),
        }
    }
    let mut rows = Vec::new();
    let truth_clouds = epoch_clouds(&truth_project)?;
    let align_clouds = if bench.truth_only {
        Vec::new()
    } else {
        epoch_clouds(&project)?
    };
    for (e, epoch) in project.epochs.iter().enumerate() {
        let truth = Truth::new(&spec, e, &truth_cameras, &epoch.name)?;
        let score_of =
            |clouds: &[Vec<Vector3<f64>>]| clouds.get(e).map(|c| truth.score(c, bench.level));
        let row = Row {
            scene: scene.to_string(),
            epoch: epoch.name.clone(),
            gsd_m: truth.gsd,
            truth: truth.score_with_map(
                &truth_clouds[e],
                bench.level,
                Some(
                    &bench
                        .out
                        .join(format!("{scene}-{}-completeness-truth.png", epoch.name)),
                ),
            ),
            align: align_clouds.get(e).map(|c| {
                truth.score_with_map(
                    c,
                    bench.level,
                    Some(
                        &bench
                            .out
                            .join(format!("{scene}-{}-completeness.png", epoch.name)),
                    ),
                )
            }),
            peer: peer_points[e].as_ref().map(|p| truth.score(p, bench.level)),
            truth_before: score_of(&before),
            align_before: score_of(&align_before),
            openmvs: openmvs_points[e]
                .as_ref()
                .map(|p| truth.score(p, bench.level)),
        };
        let line = |what: &str, s: &Option<Score>| {
            s.as_ref().map_or(String::new(), |s| {
                format!(
                    "; {what} median {:.2} p90 {:.2}, complete {:.3}",
                    s.median_gsd, s.p90_gsd, s.completeness
                )
            })
        };
        println!(
            "{scene} {}: truth cams median {:.2} p90 {:.2} GSD, complete {:.3}{}{}{}{}",
            row.epoch,
            row.truth.median_gsd,
            row.truth.p90_gsd,
            row.truth.completeness,
            line("align cams", &row.align),
            line("baseline truth cams", &row.truth_before),
            line("baseline align cams", &row.align_before),
            line("SGBM", &row.peer),
        );
        if row.openmvs.is_some() {
            println!("{scene} {}{}", row.epoch, line("OpenMVS", &row.openmvs));
        }
        rows.push(row);
    }
    Ok((rows, timing))
}

/// Each epoch's dense cloud of a project, in epoch order.
pub(crate) fn epoch_clouds(project: &Project) -> anyhow::Result<Vec<Vec<Vector3<f64>>>> {
    project
        .epochs
        .iter()
        .map(|epoch| {
            let las =
                timesift_io::pointcloud::read_las(&project.layout().dense_cloud(&epoch.name))?;
            Ok(las
                .positions
                .iter()
                .map(|q| Vector3::new(q[0], q[1], q[2]))
                .collect())
        })
        .collect()
}

/// Megapixels of the depth maps at the level: each epoch's images with sources, at its first
/// image's size divided by the level (a scene's epochs each have one camera).
pub(crate) fn depth_map_megapixels(
    project: &Project,
    report: &timesift::report::DenseReport,
    level: u32,
) -> anyhow::Result<f64> {
    let mut megapixels = 0.0;
    for (e, epoch) in project.epochs.iter().enumerate() {
        let Some(first) = project.images.iter().position(|i| i.epoch.0 as usize == e) else {
            continue;
        };
        let path = project.dir.join(&project.images[first].name);
        let (w, h) = image::image_dimensions(&path).with_context(|| path.display().to_string())?;
        let with_sources = report
            .epochs
            .get(&epoch.name)
            .map_or(0, |d| d.images_with_sources);
        megapixels += with_sources as f64 * (w / level) as f64 * (h / level) as f64 / 1e6;
    }
    Ok(megapixels)
}

/// Sets `[dense] level` in a project's `project.toml`.
pub(crate) fn set_level(dir: &Path, level: u32) -> anyhow::Result<()> {
    let path = dir.join("project.toml");
    let mut text = std::fs::read_to_string(&path)?;
    text.push_str(&format!("\n[dense]\nlevel = {level}\n"));
    std::fs::write(&path, text)?;
    Ok(())
}

/// A copy of the project (its inputs linked: images, truth, calibration files, tables) whose
/// orientation is the truth (sparse points on the true surface every 15 GSD).
fn truth_copy(spec: &SceneSpec, dir: &Path, truth_dir: &Path) -> anyhow::Result<Project> {
    let _ = std::fs::remove_dir_all(truth_dir);
    std::fs::create_dir_all(truth_dir)?;
    for entry in std::fs::read_dir(dir)? {
        let name = entry?.file_name();
        if ["work", "out", "project.toml"].iter().any(|n| name == *n) {
            continue;
        }
        std::os::unix::fs::symlink(
            std::fs::canonicalize(dir.join(&name))?,
            truth_dir.join(&name),
        )?;
    }
    std::fs::copy(dir.join("project.toml"), truth_dir.join("project.toml"))?;
    write_true_orientation(truth_dir, spec, 15.0)?;
    let project = Project::load(truth_dir)?;
    // Film scans get the interior orientations the pipeline would give them.
    timesift::stages::fiducials_stage(&project)?;
    Ok(project)
}

/// The truth of one epoch of a scene, with what scoring needs.
pub struct Truth<'a> {
    epoch: TrueEpoch<'a>,
    /// Ground sampling distance, metres (see [`TrueEpoch::gsd`]).
    pub gsd: f64,
    /// The ground sampling distance where the images see the surface from furthest: the 90th
    /// percentile over the surface of the finest image's GSD there. Completeness cells are
    /// 2 × 2 working pixels of this size, so that one point per working pixel fills them.
    pub gsd_far: f64,
}

impl<'a> Truth<'a> {
    pub fn new(
        spec: &'a SceneSpec,
        epoch: usize,
        truth: &Reconstruction,
        name: &str,
    ) -> anyhow::Result<Truth<'a>> {
        let epoch = TrueEpoch::new(spec, epoch, truth, name)?;
        let gsd = epoch.gsd;
        let mut t = Truth {
            epoch,
            gsd,
            gsd_far: gsd,
        };
        t.gsd_far = t.far_gsd();
        Ok(t)
    }

    /// The 90th percentile over surface samples (every 10 GSD) of the finest GSD of the
    /// images seeing each.
    fn far_gsd(&self) -> f64 {
        let e = &self.epoch;
        let (x0, y0, gcell, nx, ny) = e.spec.grid;
        let step = 10.0 * self.gsd;
        let (cw, ch) = (
            ((nx - 1) as f64 * gcell / step) as usize,
            ((ny - 1) as f64 * gcell / step) as usize,
        );
        let mut local: Vec<f64> = (0..cw * ch)
            .into_par_iter()
            .filter_map(|k| {
                let (g1, g2) = (
                    x0 + ((k % cw) as f64 + 0.5) * step,
                    y0 + ((k / cw) as f64 + 0.5) * step,
                );
                let x = e.surface_point(g1, g2)?;
                e.seeing(&x)
                    .into_iter()
                    .map(|v| {
                        let (camera, pose) = &e.cameras[v];
                        (x - pose.center()).norm() / focal(camera)
                    })
                    .min_by(f64::total_cmp)
            })
            .collect();
        if local.is_empty() {
            return self.gsd;
        }
        local.sort_by(f64::total_cmp);
        local[(local.len() - 1) * 9 / 10]
    }

    /// Textured land at a world position of a ground scene.
    pub fn textured_at(&self, x: f64, y: f64) -> bool {
        let o = self.epoch.spec.origin;
        self.textured(x - o.x, y - o.y)
    }

    /// Textured land: a land cover of full contrast, away from blocks (3 GSD).
    fn textured(&self, g1: f64, g2: f64) -> bool {
        let e = &self.epoch;
        let m = (e.spec.cover)(e.epoch, g1, g2);
        let textured = match e.spec.materials.get(m) {
            Some(Material::Cover { contrast, .. }) => *contrast >= 1.0,
            Some(Material::Flat(_)) | None => false,
            Some(_) => true,
        };
        textured
            && !e
                .spec
                .blocks
                .iter()
                .any(|b| b.epochs.contains(&e.epoch) && b.block.covers(g1, g2, 3.0 * self.gsd))
    }

    /// Scores a cloud (world coordinates) made at `level`.
    pub fn score(&self, cloud: &[Vector3<f64>], level: u32) -> Score {
        self.score_with_map(cloud, level, None)
    }

    /// [`Truth::score`], also writing the completeness map as a PNG when `png` is given:
    /// filled eligible cells green, empty ones red, ineligible ones grey (not textured) or black
    /// (seen by fewer than three images).
    pub fn score_with_map(&self, cloud: &[Vector3<f64>], level: u32, png: Option<&Path>) -> Score {
        let e = &self.epoch;
        let (x0, y0, gcell, nx, ny) = e.spec.grid;
        let (w, h) = ((nx - 1) as f64 * gcell, (ny - 1) as f64 * gcell);
        let cell = 2.0 * level as f64 * self.gsd_far;
        let (cw, ch) = ((w / cell) as usize, (h / cell) as usize);
        let mut hit = vec![false; cw * ch];
        let mut errors = Vec::new();
        for p in cloud {
            let (g1, g2, z) = e.grid_of(&(p - e.spec.origin));
            let (i, j) = ((g1 - x0) / cell, (g2 - y0) / cell);
            if i < 0.0 || j < 0.0 || i >= cw as f64 || j >= ch as f64 {
                continue;
            }
            hit[j as usize * cw + i as usize] = true;
            if !self.textured(g1, g2) {
                continue;
            }
            if let Some(t) = e.surface_height(g1, g2) {
                errors.push((z - t).abs() / self.gsd);
            }
        }
        // 0: not textured, 1: seen by fewer than 3 images, 2: eligible.
        let class: Vec<u8> = (0..cw * ch)
            .into_par_iter()
            .map(|k| {
                let (g1, g2) = (
                    x0 + ((k % cw) as f64 + 0.5) * cell,
                    y0 + ((k / cw) as f64 + 0.5) * cell,
                );
                if !self.textured(g1, g2) {
                    0
                } else if e
                    .surface_point(g1, g2)
                    .is_some_and(|x| e.seeing(&x).len() >= 3)
                {
                    2
                } else {
                    1
                }
            })
            .collect();
        let eligible: Vec<bool> = class.iter().map(|&c| c == 2).collect();
        if let Some(png) = png {
            let mut img = image::RgbImage::new(cw as u32, ch as u32);
            for (k, &c) in class.iter().enumerate() {
                let colour = match (c, hit[k]) {
                    (0, _) => [128, 128, 128],
                    (1, _) => [0, 0, 0],
                    (_, true) => [40, 200, 40],
                    _ => [220, 30, 30],
                };
                // North up: grid rows grow northwards.
                img.put_pixel(
                    (k % cw) as u32,
                    (ch - 1 - k / cw) as u32,
                    image::Rgb(colour),
                );
            }
            let _ = img.save(png);
        }
        let cells = eligible.iter().filter(|&&e| e).count();
        let filled = eligible
            .iter()
            .zip(&hit)
            .filter(|(e, h)| **e && **h)
            .count();
        errors.sort_by(f64::total_cmp);
        let q = |f: f64| {
            if errors.is_empty() {
                f64::NAN
            } else {
                errors[((errors.len() - 1) as f64 * f).round() as usize]
            }
        };
        Score {
            points: cloud.len(),
            evaluated: errors.len(),
            median_gsd: q(0.5),
            p90_gsd: q(0.9),
            completeness: filled as f64 / cells.max(1) as f64,
            cells,
        }
    }
}

/// Whether a score meets the bar (median ≤ 0.5 GSD, p90 ≤ 2 GSD, completeness ≥ 90 %).
fn meets(s: &Score) -> bool {
    s.median_gsd <= 0.5 && s.p90_gsd <= 2.0 && s.completeness >= 0.9
}

fn table(rows: &[Row], timings: &[Timing], level: u32) -> String {
    let mut t = format!(
        "\n## Dense clouds against the truth (level {level}; textured land; |error| in GSD)\n\n\
         | scene | epoch | GSD m | true cams median / p90 / complete | baseline, true cams | align cams median / p90 / complete | baseline, align cams | OpenCV SGBM median / p90 / complete | bar met (true, align) | better than SGBM |\n\
         |---|---|---|---|---|---|---|---|---|---|\n"
    );
    let s = |x: &Score| {
        format!(
            "{:.2} / {:.2} / {:.1} %",
            x.median_gsd,
            x.p90_gsd,
            100.0 * x.completeness
        )
    };
    let opt = |x: &Option<Score>| x.as_ref().map_or("–".to_string(), s);
    let met = |x: Option<&Score>| match x {
        Some(x) if meets(x) => "yes",
        Some(_) => "NO",
        None => "–",
    };
    for r in rows {
        let better = r.peer.as_ref().map_or("–".to_string(), |p| {
            let acc = r.truth.median_gsd < p.median_gsd && r.truth.p90_gsd < p.p90_gsd;
            let com = r.truth.completeness > p.completeness;
            format!(
                "{} accuracy, {} completeness",
                if acc { "more" } else { "NOT more" },
                if com { "more" } else { "NOT more" }
            )
        });
        t.push_str(&format!(
            "| {} | {} | {:.3} | {} | {} | {} | {} | {} | {}, {} | {} |\n",
            r.scene,
            r.epoch,
            r.gsd_m,
            s(&r.truth),
            opt(&r.truth_before),
            opt(&r.align),
            opt(&r.align_before),
            opt(&r.peer),
            met(Some(&r.truth)),
            met(r.align.as_ref()),
            better
        ));
    }
    t.push_str(
        "\n## Cost of the dense stage (true cameras; a process of its own: wall and CPU seconds, peak resident memory; core-seconds per depth-map megapixel = CPU seconds / MP)\n\n\
         | scene | images | depth-map MP | build | threads | wall s | CPU s | core-s / MP | peak MiB |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    for m in timings {
        let runs = m
            .baseline_runs
            .iter()
            .map(|r| ("baseline", r))
            .chain(m.runs.iter().map(|r| ("this", r)));
        for (build, r) in runs {
            t.push_str(&format!(
                "| {} | {} | {:.2} | {build} | {} | {:.1} | {:.1} | {:.1} | {:.0} |\n",
                m.scene,
                m.images,
                m.megapixels,
                r.threads,
                r.wall,
                r.cpu,
                r.cpu / m.megapixels,
                r.peak_mib
            ));
        }
        for (before, after) in m.baseline_runs.iter().zip(&m.runs) {
            t.push_str(&format!(
                "| {} | | | speed-up | {} | {:.2}× | {:.2}× | | |\n",
                m.scene,
                after.threads,
                before.wall / after.wall,
                before.cpu / after.cpu
            ));
        }
    }
    t.push_str(
        "\n## Where this build's time went (2 threads, wall seconds, all epochs; out/dense.json phase_seconds)\n\n\
         | scene | images | photometric | hierarchy | geometric | refine | map files | filter | fusion | cloud file |\n|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for m in timings {
        let p = &m.phases;
        t.push_str(&format!(
            "| {} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} |\n",
            m.scene,
            p.images,
            p.photometric,
            p.hierarchy,
            p.geometric,
            p.refine,
            p.map_files,
            p.filter,
            p.fusion,
            p.cloud_file
        ));
    }
    if timings.iter().any(|m| m.openmvs.is_some()) {
        t.push_str(
            "\n## OpenMVS DensifyPointCloud (CPU) on the same images and true cameras, 2 threads, depth maps of the same size\n\n\
             | scene | epoch | OpenMVS median / p90 / complete | this build |\n|---|---|---|---|\n",
        );
        for r in rows.iter().filter(|r| r.openmvs.is_some()) {
            t.push_str(&format!(
                "| {} | {} | {} | {} |\n",
                r.scene,
                r.epoch,
                opt(&r.openmvs),
                s(&r.truth)
            ));
        }
        t.push_str(
            "\n| scene | depth-map MP | OpenMVS CPU s | core-s / MP | peak MiB | this build's core-s / MP | OpenMVS ÷ this |\n|---|---|---|---|---|---|---|\n",
        );
        for m in timings {
            let (Some(o), Some(this)) = (m.openmvs, m.runs.iter().find(|r| r.threads == 2)) else {
                continue;
            };
            t.push_str(&format!(
                "| {} | {:.2} | {:.1} | {:.1} | {:.0} | {:.1} | {:.2}× |\n",
                m.scene,
                m.megapixels,
                o.cpu,
                o.cpu / m.megapixels,
                o.peak_mib,
                this.cpu / m.megapixels,
                o.cpu / this.cpu
            ));
        }
    }
    t.push_str(
        "\n## OpenCV SGBM, seconds per image (rectification, matching, triangulation)\n\n\
         | scene | images | 1 thread | 2 threads |\n|---|---|---|---|\n",
    );
    for m in timings {
        if let (Some(a), Some(b)) = (m.peer_1, m.peer_2) {
            t.push_str(&format!(
                "| {} | {} | {a:.3} | {b:.3} |\n",
                m.scene, m.images
            ));
        }
    }
    t
}
