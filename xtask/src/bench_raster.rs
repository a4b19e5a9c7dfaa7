//! `cargo xtask bench raster`: the `dem` and `ortho` stages on the ground scenes of `synth`.
//!
//! Clouds: the true surfaces sampled at the dense stage's density (one point per 2 × 2 GSD, as
//! level 2 gives) with 0.5 GSD of height noise, on the true orientation; and, when
//! `cargo xtask bench dense` has left its projects in `--dense-dir`, the dense stage's own
//! clouds with the align stage's cameras and with the true ones.
//!
//! Per scene and epoch: the DEM against `truth/dem_<epoch>.tif` on textured land (mean and
//! NMAD in GSD, measured cells; all of it, and where the true slope is under 20°: a cell of
//! 2 GSD across a tree crown's edge holds crown and ground, which no statistic of its points
//! makes the crown's height), the stable-area DEM of difference against the first epoch
//! (median, mean, and the tilt of a plane fitted to it: the height it gains across the stable
//! area, in GSD — what check points along a corridor cannot see), the painted targets located
//! in each ortho (RMSE in ortho cells), the colour step across ortho seams beside the texture's
//! own step between neighbouring cells, and the ortho time per output megapixel on 1 and 2
//! threads. Then DEM gridding against GDAL's `gdal_grid` on the same points and grid, and
//! `gdalinfo` on the products. PNGs of the `orchard` and `shore` orthos are written for a person
//! to look at.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::Context;
use timesift::Project;
use timesift::layout::Layout;
use timesift::report::{GridFile, RasterReport, read_json};
use timesift::stages::{Stage, run_stage};
use timesift_change::grid::Dem;
use timesift_change::stats::{median, nmad};
use timesift_change::trend::plane_trend;
use timesift_eval::products::{dem_height_errors, ortho_target_errors};
use timesift_eval::true_scene::{write_sampled_clouds, write_true_orientation};
use timesift_io::cameras_json::read_cameras_json;
use timesift_io::geotiff::{GeoRaster, read_f32, read_rgb8};
use timesift_synth::scene::{Frame, SceneSpec};

use crate::bench_dense::Truth;

/// What to run.
pub struct RasterBench {
    pub scenes: Vec<String>,
    pub seed: u64,
    pub out: PathBuf,
    /// Where `cargo xtask bench dense` left its projects (`<scene>`, `<scene>-truth`).
    pub dense_dir: Option<PathBuf>,
    pub peer: bool,
}

/// DEM scores of one epoch.
#[derive(Debug, Clone, Default, serde::Serialize)]
struct DemScore {
    cells: usize,
    mean_gsd: f64,
    nmad_gsd: f64,
    /// The same on textured land whose true slope is under 20° (no tree crowns, no walls).
    gentle_cells: usize,
    gentle_mean_gsd: f64,
    gentle_nmad_gsd: f64,
    /// Stable-area DoD against the first epoch: cells, median, mean, plane tilt (GSD).
    dod_cells: usize,
    dod_median_gsd: Option<f64>,
    dod_mean_gsd: Option<f64>,
    dod_tilt_gsd: Option<f64>,
}

#[derive(Debug, Clone, Default, serde::Serialize)]
struct OrthoScore {
    targets: usize,
    target_rmse_cells: Option<f64>,
    seam_jump: Option<f64>,
    interior_jump: Option<f64>,
    painted: Option<f64>,
}

#[derive(Debug, Clone, serde::Serialize)]
struct Row {
    scene: String,
    epoch: String,
    cloud: String,
    gsd_m: f64,
    dem_cell_m: f64,
    dem: DemScore,
    ortho: Option<OrthoScore>,
}

#[derive(Debug, Clone, serde::Serialize)]
struct OrthoTiming {
    scene: String,
    megapixels: f64,
    seconds_1: f64,
    seconds_2: f64,
}

pub fn run_bench(bench: &RasterBench) -> anyhow::Result<()> {
    std::fs::create_dir_all(&bench.out).with_context(|| bench.out.display().to_string())?;
    let mut rows = Vec::new();
    let mut timings = Vec::new();
    let mut peer_text = String::new();
    for scene in &bench.scenes {
        let spec =
            timesift_synth::scenes::build(scene, timesift_synth::scenes::Scale::Small, bench.seed)?;
        if spec.frame != Frame::Ground {
            println!("{scene}: skipped (a wall: its truth is not a DEM seen from above)");
            continue;
        }
        let dir = bench.out.join(scene);
        let _ = std::fs::remove_dir_all(&dir);
        timesift_synth::writer::write_scene(
            &spec,
            &dir,
            &timesift_synth::writer::WriteOptions::default(),
        )?;
        write_true_orientation(&dir, &spec, 15.0)?;
        // Film scans get the interior orientations the pipeline would give them.
        timesift::stages::fiducials_stage(&Project::load(&dir)?)?;
        let gsds = write_sampled_clouds(&dir, &spec, 2.0, 0.5, bench.seed)?;
        let project = Project::load(&dir)?;
        crate::bench_dense::pool(2)?.install(|| run_stage(&project, Stage::Dem))?;
        crate::bench_dense::pool(2)?.install(|| run_stage(&project, Stage::Ortho))?;
        let seconds_2: f64 = raster_report(&dir)?
            .epochs
            .values()
            .filter_map(|e| e.ortho_seconds)
            .sum();
        for (name, _) in &gsds {
            let _ = std::fs::remove_file(project.layout().raster_settings(name, "ortho"));
        }
        crate::bench_dense::pool(1)?.install(|| run_stage(&project, Stage::Ortho))?;
        let seconds_1: f64 = raster_report(&dir)?
            .epochs
            .values()
            .filter_map(|e| e.ortho_seconds)
            .sum();
        let grid: GridFile = read_json(&dir.join("out/grid.json"))?;
        let megapixels = (grid.ortho_size[0] * grid.ortho_size[1] * gsds.len()) as f64 / 1e6;
        timings.push(OrthoTiming {
            scene: scene.clone(),
            megapixels,
            seconds_1,
            seconds_2,
        });
        rows.extend(score_project(&spec, &dir, "sampled", true)?);
        if matches!(scene.as_str(), "orchard" | "shore") {
            for (name, _) in &gsds {
                ortho_pngs(&dir, name, &bench.out.join(format!("{scene}-{name}")))?;
            }
        }
        if peer_text.is_empty() && bench.peer {
            peer_text = gdal_grid_comparison(&spec, &dir, &gsds[0].0, &bench.out)?;
        }
        if let Some(dense) = &bench.dense_dir {
            for (suffix, label) in [
                ("", "dense, align cameras"),
                ("-truth", "dense, true cameras"),
            ] {
                let d = dense.join(format!("{scene}{suffix}"));
                let p = Project::load(&d);
                let have = p.as_ref().is_ok_and(|p| {
                    p.epochs
                        .iter()
                        .all(|e| p.layout().dense_cloud(&e.name).is_file())
                });
                let (Ok(p), true) = (p, have) else {
                    println!(
                        "{scene}: no dense clouds in {} (run cargo xtask bench dense)",
                        d.display()
                    );
                    continue;
                };
                let _ = std::fs::remove_file(p.layout().grid_json());
                crate::bench_dense::pool(2)?.install(|| run_stage(&p, Stage::Dem))?;
                let with_ortho = suffix.is_empty();
                if with_ortho {
                    crate::bench_dense::pool(2)?.install(|| run_stage(&p, Stage::Ortho))?;
                }
                rows.extend(score_project(&spec, &d, label, with_ortho)?);
            }
        }
        let text = table(&rows, &timings, &peer_text);
        std::fs::write(bench.out.join("raster.md"), &text)?;
    }
    let mut text = table(&rows, &timings, &peer_text);
    text.push_str(&gdalinfo_summary(&bench.out, &bench.scenes)?);
    crate::write_results(
        &bench.out,
        "raster",
        &text,
        &serde_json::json!({ "rows": rows, "timings": timings }),
    )
}

fn raster_report(dir: &Path) -> anyhow::Result<RasterReport> {
    Ok(read_json(&dir.join("out/raster.json"))?)
}

/// Scores every epoch's DEM (and ortho) of a project on a scene.
fn score_project(
    spec: &SceneSpec,
    dir: &Path,
    cloud: &str,
    with_ortho: bool,
) -> anyhow::Result<Vec<Row>> {
    let project = Project::load(dir)?;
    let truth_cameras = read_cameras_json(&project.layout().truth_cameras())?;
    let grid: GridFile = read_json(&project.layout().grid_json())?;
    let report = raster_report(dir)?;
    let mut rows = Vec::new();
    let mut first: Option<GeoRaster<f32>> = None;
    for (e, epoch) in project.epochs.iter().enumerate() {
        let name = &epoch.name;
        let truth = Truth::new(spec, e, &truth_cameras, name)?;
        let gsd = truth.gsd;
        let dem = read_f32(&project.layout().dem(name))?;
        let count = read_f32(&project.layout().dem_count(name))?;
        let true_dem =
            Dem::from_raster(read_f32(&dir.join(format!("truth/dem_{name}.tif")))?, None)?;
        let mut err: Vec<f64> =
            dem_height_errors(&dem, &count, &true_dem, |x, y| truth.textured_at(x, y))
                .into_iter()
                .map(|e| e / gsd)
                .collect();
        let cell = grid.dem_cell;
        let gentle = |x: f64, y: f64| {
            let h = |dx: f64, dy: f64| true_dem.bilinear(x + dx, y + dy);
            let (e, w, n, s) = (h(cell, 0.0), h(-cell, 0.0), h(0.0, cell), h(0.0, -cell));
            // NaN (a side without truth) fails the comparison: not gentle.
            ((e - w) / (2.0 * cell)).hypot((n - s) / (2.0 * cell)) < 20f64.to_radians().tan()
        };
        let mut gentle_err: Vec<f64> = dem_height_errors(&dem, &count, &true_dem, |x, y| {
            truth.textured_at(x, y) && gentle(x, y)
        })
        .into_iter()
        .map(|e| e / gsd)
        .collect();
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        let mut score = DemScore {
            cells: err.len(),
            mean_gsd: mean(&err),
            nmad_gsd: nmad(&mut err),
            gentle_cells: gentle_err.len(),
            gentle_mean_gsd: mean(&gentle_err),
            gentle_nmad_gsd: nmad(&mut gentle_err),
            ..DemScore::default()
        };
        if let Some(base) = &first {
            stable_dod(spec, base, &dem, gsd, &mut score);
        }
        let ortho = if with_ortho {
            Some(score_ortho(spec, dir, name, &report)?)
        } else {
            None
        };
        rows.push(Row {
            scene: spec.name.clone(),
            epoch: name.clone(),
            cloud: cloud.to_string(),
            gsd_m: gsd,
            dem_cell_m: grid.dem_cell,
            dem: score,
            ortho,
        });
        if first.is_none() {
            first = Some(dem);
        }
    }
    Ok(rows)
}

/// The DEM of difference (later − first) over stable ground: median, mean and the tilt of a
/// least-squares plane, as the height it gains across the stable cells' extent.
fn stable_dod(
    spec: &SceneSpec,
    base: &GeoRaster<f32>,
    dem: &GeoRaster<f32>,
    gsd: f64,
    score: &mut DemScore,
) {
    let t = dem.georef.transform;
    let o = spec.origin;
    let mut samples = Vec::new();
    for r in 0..dem.height {
        for c in 0..dem.width {
            let (a, b) = (base.get(c, r, 0), dem.get(c, r, 0));
            if a == -32767.0 || b == -32767.0 {
                continue;
            }
            let (x, y) = t.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
            if spec.is_stable(x - o.x, y - o.y) {
                samples.push((x, y, (b - a) as f64));
            }
        }
    }
    score.dod_cells = samples.len();
    if samples.len() < 10 {
        return;
    }
    let mut dz: Vec<f64> = samples.iter().map(|s| s.2).collect();
    score.dod_mean_gsd = Some(dz.iter().sum::<f64>() / dz.len() as f64 / gsd);
    score.dod_median_gsd = Some(median(&mut dz) / gsd);
    // The stable cells' differences as a grid (NaN elsewhere), for the change crate's plane.
    let Ok(mut diff) = Dem::from_raster(base.clone(), Some(-32767.0)) else {
        return;
    };
    diff.values.fill(f32::NAN);
    for &(x, y, z) in &samples {
        let (c, r) = t.world_to_pixel(x, y);
        diff.values[r as usize * dem.width + c as usize] = z as f32;
    }
    if let Ok(trend) = plane_trend(&diff, None) {
        score.dod_tilt_gsd = Some(trend.gain_m / gsd);
    }
}

fn score_ortho(
    spec: &SceneSpec,
    dir: &Path,
    name: &str,
    report: &RasterReport,
) -> anyhow::Result<OrthoScore> {
    let ortho = read_rgb8(&dir.join("out/epochs").join(name).join("ortho.tif"))?;
    let (found, rmse) = ortho_target_errors(&Layout::new(dir), &ortho, spec.target_radius)?;
    let r = report.epochs.get(name).cloned().unwrap_or_default();
    Ok(OrthoScore {
        targets: found,
        target_rmse_cells: rmse,
        seam_jump: r.seam_jump,
        interior_jump: r.interior_jump,
        painted: r.ortho_painted_fraction,
    })
}

/// The ortho preview, and a full-resolution crop of 1024 × 1024 cells from the middle.
fn ortho_pngs(dir: &Path, epoch: &str, stem: &Path) -> anyhow::Result<()> {
    let epoch_dir = dir.join("out/epochs").join(epoch);
    std::fs::copy(epoch_dir.join("ortho.png"), stem.with_extension("png"))?;
    let ortho = read_rgb8(&epoch_dir.join("ortho.tif"))?;
    let side = 1024.min(ortho.width).min(ortho.height);
    let (c0, r0) = ((ortho.width - side) / 2, (ortho.height - side) / 2);
    let mut crop = Vec::with_capacity(side * side * 4);
    for r in r0..r0 + side {
        let i = 4 * (r * ortho.width + c0);
        crop.extend_from_slice(&ortho.data[i..i + 4 * side]);
    }
    let path = PathBuf::from(format!("{}-full-resolution.png", stem.display()));
    timesift_io::image::write_png(&path, side as u32, side as u32, 4, &crop)?;
    Ok(())
}

/// DEM gridding of one cloud onto one grid: `timesift dem` (end to end, and the gridding alone
/// in process) against GDAL's `gdal_grid` (moving average in a circle circumscribing the
/// cell, its closest algorithm to a per-cell statistic; GDAL 3.6 has no median).
fn gdal_grid_comparison(
    spec: &SceneSpec,
    dir: &Path,
    epoch: &str,
    out: &Path,
) -> anyhow::Result<String> {
    // The epoch's surface sampled as a level-1 dense cloud would be (one point per GSD², four
    // per DEM cell), in a folder of its own beside the scene.
    let work = out.join("gdal-grid");
    let _ = std::fs::remove_dir_all(&work);
    std::fs::create_dir_all(&work)?;
    std::os::unix::fs::symlink(
        std::fs::canonicalize(dir.join("truth"))?,
        work.join("truth"),
    )?;
    write_sampled_clouds(&work, spec, 1.0, 0.5, 11)?;
    let cloud_path = work.join("out/epochs").join(epoch).join("dense.laz");
    let dem_path = dir.join("out/epochs").join(epoch).join("dem.tif");
    let cloud = timesift_io::pointcloud::read_las_positions(&cloud_path)?;
    let like = timesift_io::geotiff::read_grid(&dem_path)?;
    let t = like.georef.transform;
    let cell = t.pixel_width;
    let csv = work.join("points.csv");
    let mut text = String::from("x,y,z\n");
    for p in &cloud.positions {
        text.push_str(&format!("{:.4},{:.4},{:.4}\n", p[0], p[1], p[2]));
    }
    std::fs::write(&csv, text)?;
    let vrt = work.join("points.vrt");
    std::fs::write(
        &vrt,
        format!(
            "<OGRVRTDataSource><OGRVRTLayer name=\"points\"><SrcDataSource>{}</SrcDataSource>\
             <GeometryType>wkbPoint</GeometryType><GeometryField encoding=\"PointFromColumns\" \
             x=\"x\" y=\"y\" z=\"z\"/></OGRVRTLayer></OGRVRTDataSource>",
            csv.display()
        ),
    )?;
    let (x0, y0) = t.pixel_to_world(0.0, 0.0);
    let (x1, y1) = t.pixel_to_world(like.width as f64, like.height as f64);
    let radius = cell * std::f64::consts::FRAC_1_SQRT_2;
    let gdal_out = work.join("gdal_grid.tif");
    let run_gdal = || -> anyhow::Result<f64> {
        let start = Instant::now();
        let status = Command::new("gdal_grid")
            .args([
                "-q",
                "--config",
                "GDAL_NUM_THREADS",
                "ALL_CPUS",
                "-a",
                &format!("average:radius1={radius}:radius2={radius}:min_points=1:nodata=-32767"),
                "-zfield",
                "z",
                "-txe",
                &x0.to_string(),
                &x1.to_string(),
                "-tye",
                &y0.to_string(),
                &y1.to_string(),
                "-outsize",
                &like.width.to_string(),
                &like.height.to_string(),
                "-ot",
                "Float32",
                "-l",
                "points",
            ])
            .arg(&vrt)
            .arg(&gdal_out)
            .status()
            .context("running gdal_grid (apt-get install gdal-bin)")?;
        anyhow::ensure!(status.success(), "gdal_grid failed");
        Ok(start.elapsed().as_secs_f64())
    };
    let run_ours = || -> anyhow::Result<f64> {
        let start = Instant::now();
        timesift::commands::dem::dem(&timesift::commands::dem::DemRequest {
            cloud: cloud_path.clone(),
            cell: None,
            like: Some(dem_path.clone()),
            out: work.join("timesift_dem.tif"),
            method: timesift::commands::dem::DemMethod::Median,
            idw_radius: 1.5,
            min_points: 1,
            max_gap: 0,
        })?;
        Ok(start.elapsed().as_secs_f64())
    };
    // The best of three runs of each, alternating (the machine's other load shows in single
    // runs: gdal_grid took 2.2 to 3.4 s on this cloud).
    let (mut gdal_seconds, mut ours_seconds) = (f64::INFINITY, f64::INFINITY);
    for _ in 0..3 {
        gdal_seconds = gdal_seconds.min(run_gdal()?);
        ours_seconds = ours_seconds.min(run_ours()?);
    }
    let lattice = timesift_raster::Lattice::new(x0, y0, cell, like.width, like.height)?;
    let start = Instant::now();
    let dem = timesift_raster::grid_cloud(
        &cloud.positions,
        &lattice,
        &timesift_raster::DemOptions {
            max_gap: 0,
            ..Default::default()
        },
    )?;
    let in_process = start.elapsed().as_secs_f64();
    // Agreement of the two DEMs (they use different statistics: a sanity check).
    let theirs = read_f32(&gdal_out)?;
    let flip = theirs.georef.transform.pixel_height > 0.0;
    let mut diff = Vec::new();
    for r in 0..like.height {
        for c in 0..like.width {
            let rr = if flip { like.height - 1 - r } else { r };
            let (a, b) = (dem.height[r * like.width + c], theirs.get(c, rr, 0));
            if a.is_finite() && b != -32767.0 {
                diff.push((a - b) as f64);
            }
        }
    }
    let cells_in_both = diff.len();
    let agreement = nmad(&mut diff);
    Ok(format!(
        "\n## DEM gridding against GDAL (`{}` epoch {epoch}: {} points onto {} × {} cells of {cell} m)\n\n\
         | | seconds | ratio (gdal_grid / timesift) |\n|---|---|---|\n\
         | gdal_grid average (end to end, best of 3) | {gdal_seconds:.3} | |\n\
         | timesift dem median (end to end, in process, best of 3: read LAZ, grid, write 4 GeoTIFFs + PNG) | {ours_seconds:.3} | {:.1}× |\n\
         | timesift gridding alone (median, in process) | {in_process:.4} | {:.0}× |\n\n\
         NMAD of the difference between the two DEMs: {agreement:.4} m ({} cells in both).\n",
        dir.file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default(),
        cloud.positions.len(),
        like.width,
        like.height,
        gdal_seconds / ours_seconds,
        gdal_seconds / in_process,
        cells_in_both,
    ))
}

/// What `gdalinfo` says of one DEM and one ortho.
fn gdalinfo_summary(out: &Path, scenes: &[String]) -> anyhow::Result<String> {
    let Some(scene) = scenes
        .iter()
        .find(|s| out.join(s).join("out/grid.json").is_file())
    else {
        return Ok(String::new());
    };
    let dir = out.join(scene).join("out/epochs");
    let Some(epoch) = std::fs::read_dir(&dir)?.flatten().map(|e| e.path()).min() else {
        return Ok(String::new());
    };
    let mut text = format!("\n## gdalinfo on {}\n\n```\n", epoch.display());
    for file in ["dem.tif", "ortho.tif"] {
        let o = Command::new("gdalinfo").arg(epoch.join(file)).output();
        let Ok(o) = o else {
            text.push_str("gdalinfo not installed (apt-get install gdal-bin)\n");
            break;
        };
        let stdout = String::from_utf8_lossy(&o.stdout);
        // The CRS's own EPSG code is the last ID of the WKT (earlier ones are its parts).
        let epsg = stdout.lines().rfind(|l| l.contains("ID[\"EPSG\""));
        for line in stdout.lines().filter(|l| {
            [
                "Size is",
                "Origin",
                "Pixel Size",
                "Block=",
                "NoData",
                "Overviews:",
                "COMPRESSION",
            ]
            .iter()
            .any(|k| l.contains(k))
        }) {
            text.push_str(&format!("{file}: {}\n", line.trim()));
        }
        if let Some(epsg) = epsg {
            text.push_str(&format!("{file}: CRS {}\n", epsg.trim()));
        }
        let stderr = String::from_utf8_lossy(&o.stderr);
        text.push_str(&format!(
            "{file}: warnings: {}\n",
            if stderr.trim().is_empty() {
                "none"
            } else {
                stderr.trim()
            }
        ));
    }
    text.push_str("```\n");
    Ok(text)
}

fn fmt(v: Option<f64>, digits: usize) -> String {
    v.map_or("–".into(), |v| format!("{v:.digits$}"))
}

fn table(rows: &[Row], timings: &[OrthoTiming], peer: &str) -> String {
    let mut s = String::from(
        "\n## DEMs against the truth (textured land, measured cells; GSD units) and orthos\n\n\
         Bars: DEM NMAD ≤ 0.5, |mean| ≤ 0.2; stable DoD |mean| ≤ 0.3; targets RMSE ≤ 1 ortho cell. \
         `cells < 20°`: textured land whose true slope is under 20° (tree crowns and walls out).\n\n\
         | scene | epoch | cloud | GSD m | DEM cell m | cells | mean | NMAD | cells < 20° | mean | NMAD | stable DoD median | mean | plane tilt across | targets | RMSE cells | seam step | texture step | painted |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let d = &r.dem;
        let o = r.ortho.clone().unwrap_or_default();
        s.push_str(&format!(
            "| {} | {} | {} | {:.3} | {} | {} | {:+.3} | {:.3} | {} | {:+.3} | {:.3} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
            r.scene,
            r.epoch,
            r.cloud,
            r.gsd_m,
            r.dem_cell_m,
            d.cells,
            d.mean_gsd,
            d.nmad_gsd,
            d.gentle_cells,
            d.gentle_mean_gsd,
            d.gentle_nmad_gsd,
            fmt(d.dod_median_gsd, 3),
            fmt(d.dod_mean_gsd, 3),
            fmt(d.dod_tilt_gsd, 3),
            if r.ortho.is_some() { o.targets.to_string() } else { "–".into() },
            fmt(o.target_rmse_cells, 2),
            fmt(o.seam_jump, 2),
            fmt(o.interior_jump, 2),
            fmt(o.painted, 3),
        ));
    }
    s.push_str(
        "\n## Orthomosaic time (sampled clouds, all epochs of a scene)\n\n\
         | scene | output MP | s/MP 1 thread | s/MP 2 threads |\n|---|---|---|---|\n",
    );
    for t in timings {
        s.push_str(&format!(
            "| {} | {:.1} | {:.3} | {:.3} |\n",
            t.scene,
            t.megapixels,
            t.seconds_1 / t.megapixels,
            t.seconds_2 / t.megapixels
        ));
    }
    s.push_str(peer);
    s
}
