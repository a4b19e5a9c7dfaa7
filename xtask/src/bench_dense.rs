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

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use nalgebra::Vector3;
use rayon::prelude::*;
use timesift::Project;
use timesift::stages::{Stage, run, run_stage};
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
    align: Score,
    peer: Option<Score>,
}

/// Seconds per image of the timesift pipeline and of the peer.
#[derive(Debug, Clone, Default, serde::Serialize)]
struct Timing {
    scene: String,
    images: usize,
    timesift_1: f64,
    timesift_2: f64,
    peer_1: Option<f64>,
    peer_2: Option<f64>,
}

pub fn run_bench(bench: &DenseBench) -> anyhow::Result<()> {
    std::fs::create_dir_all(&bench.out).with_context(|| bench.out.display().to_string())?;
    let mut rows = Vec::new();
    let mut timings = Vec::new();
    for scene in &bench.scenes {
        let (r, t) = bench_scene(bench, scene)?;
        rows.extend(r);
        timings.push(t);
        let text = table(&rows, &timings, bench.level);
        std::fs::write(bench.out.join("dense.md"), &text)?;
    }
    let mut text = table(&rows, &timings, bench.level);
    if bench.lund {
        text.push_str(&crate::bench_dense_lund::run(&bench.out, bench.level)?);
    }
    crate::write_results(
        &bench.out,
        "dense",
        &text,
        &serde_json::json!({ "rows": rows, "timings": timings }),
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
    let reused = bench.reuse && dir.join("out/cameras.json").is_file();
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
    if !reused {
        let start = Instant::now();
        run(&project, Some(Stage::Features), Some(Stage::Align))?;
        println!(
            "{scene}: oriented in {:.1} s",
            start.elapsed().as_secs_f64()
        );
    }
    // The align stage's cameras.
    pool(2)?.install(|| run_stage(&project, Stage::Dense))?;
    // The true cameras, with sparse points on the true surface.
    let truth_dir = bench.out.join(format!("{scene}-truth"));
    let truth_project = if reused && truth_dir.join("out/cameras.json").is_file() {
        Project::load(&truth_dir)?
    } else {
        truth_copy(&spec, &dir, &truth_dir)?
    };
    let start = Instant::now();
    pool(2)?.install(|| run_stage(&truth_project, Stage::Dense))?;
    let two = start.elapsed().as_secs_f64();
    let one = if bench.reuse {
        f64::NAN
    } else {
        // One thread, on the same work (maps removed).
        let _ = std::fs::remove_dir_all(truth_dir.join("work/dense"));
        let _ = std::fs::remove_dir_all(truth_dir.join("out/epochs"));
        let start = Instant::now();
        pool(1)?.install(|| run_stage(&truth_project, Stage::Dense))?;
        start.elapsed().as_secs_f64()
    };
    let images = project.images.len();
    let mut timing = Timing {
        scene: scene.to_string(),
        images,
        timesift_1: one / images as f64,
        timesift_2: two / images as f64,
        ..Timing::default()
    };
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
    let mut rows = Vec::new();
    for (e, epoch) in project.epochs.iter().enumerate() {
        let truth = Truth::new(&spec, e, &truth_cameras, &epoch.name)?;
        let cloud = |p: &Project| -> anyhow::Result<Vec<Vector3<f64>>> {
            let las = timesift_io::pointcloud::read_las(&p.layout().dense_cloud(&epoch.name))?;
            Ok(las
                .positions
                .iter()
                .map(|q| Vector3::new(q[0], q[1], q[2]))
                .collect())
        };
        let row = Row {
            scene: scene.to_string(),
            epoch: epoch.name.clone(),
            gsd_m: truth.gsd,
            truth: truth.score_with_map(
                &cloud(&truth_project)?,
                bench.level,
                Some(
                    &bench
                        .out
                        .join(format!("{scene}-{}-completeness-truth.png", epoch.name)),
                ),
            ),
            align: truth.score_with_map(
                &cloud(&project)?,
                bench.level,
                Some(
                    &bench
                        .out
                        .join(format!("{scene}-{}-completeness.png", epoch.name)),
                ),
            ),
            peer: peer_points[e].as_ref().map(|p| truth.score(p, bench.level)),
        };
        println!(
            "{scene} {}: truth cams median {:.2} p90 {:.2} GSD, complete {:.3}; align cams median {:.2} p90 {:.2}, complete {:.3}{}",
            row.epoch,
            row.truth.median_gsd,
            row.truth.p90_gsd,
            row.truth.completeness,
            row.align.median_gsd,
            row.align.p90_gsd,
            row.align.completeness,
            row.peer.as_ref().map_or(String::new(), |p| format!(
                "; SGBM median {:.2} p90 {:.2}, complete {:.3}",
                p.median_gsd, p.p90_gsd, p.completeness
            ))
        );
        rows.push(row);
    }
    Ok((rows, timing))
}

/// Sets `[dense] level` in a project's `project.toml`.
fn set_level(dir: &Path, level: u32) -> anyhow::Result<()> {
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
         | scene | epoch | GSD m | true cams median / p90 / complete | align cams median / p90 / complete | OpenCV SGBM median / p90 / complete | bar met (true, align) | better than SGBM |\n\
         |---|---|---|---|---|---|---|---|\n"
    );
    let s = |x: &Score| {
        format!(
            "{:.2} / {:.2} / {:.1} %",
            x.median_gsd,
            x.p90_gsd,
            100.0 * x.completeness
        )
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
            "| {} | {} | {:.3} | {} | {} | {} | {}, {} | {} |\n",
            r.scene,
            r.epoch,
            r.gsd_m,
            s(&r.truth),
            s(&r.align),
            r.peer.as_ref().map_or("–".to_string(), s),
            if meets(&r.truth) { "yes" } else { "NO" },
            if meets(&r.align) { "yes" } else { "NO" },
            better
        ));
    }
    t.push_str(
        "\n## Seconds per image (true cameras; timesift: PatchMatch passes, filtering, fusion, LAZ; SGBM: rectification, matching, triangulation)\n\n\
         | scene | images | timesift 1 thread | timesift 2 threads | SGBM 1 thread | SGBM 2 threads | ratio 1 thread | ratio 2 threads |\n|---|---|---|---|---|---|---|---|\n",
    );
    for m in timings {
        let ratio =
            |a: f64, b: Option<f64>| b.map_or("–".to_string(), |b| format!("{:.1}×", a / b));
        t.push_str(&format!(
            "| {} | {} | {:.3} | {:.3} | {} | {} | {} | {} |\n",
            m.scene,
            m.images,
            m.timesift_1,
            m.timesift_2,
            m.peer_1.map_or("–".into(), |v| format!("{v:.3}")),
            m.peer_2.map_or("–".into(), |v| format!("{v:.3}")),
            ratio(m.timesift_1, m.peer_1),
            ratio(m.timesift_2, m.peer_2),
        ));
    }
    t
}
