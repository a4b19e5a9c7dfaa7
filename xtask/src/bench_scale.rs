//! `cargo xtask bench scale`: how the cost of every stage grows with the block. `synth scale-N`
//! blocks (drone surveys over farmland with GNSS priors and control, more epochs and a larger
//! area as N grows, never denser images) at N = 100, 200, 400, 800, 1,600 images. Each stage runs
//! as a process of its own (`xtask run-stage`, this build's code) on 2 threads: wall and CPU
//! seconds, peak resident memory and the files it wrote; then the growth exponent of each stage
//! between N = 200 and the largest N (the slope of log time against log N), the check-point
//! errors and the DoDs' error over the true stable ground (median, tilt of a plane) per N.
//! Written as `scale.md`, `scale.json` and a log-log plot `scale.png` in the output folder.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant, SystemTime};

use anyhow::Context;
use timesift::Project;
use timesift::config::{DenseConfig, MapperConfig};
use timesift::stages::Stage;
use timesift_change::grid::Dem;
use timesift_change::trend::{SurfaceAgreement, residual_plane};

use crate::bench_dense_time::time_command_within;
use crate::bench_scale_colmap::PeerRow;

/// What to run.
pub struct ScaleBench {
    /// Block sizes, images.
    pub sizes: Vec<usize>,
    pub out: PathBuf,
    pub seed: u64,
    /// Rayon threads of every stage.
    pub threads: usize,
    /// A stage still running after this is killed, and the size's later stages skipped.
    pub stage_limit: Duration,
    /// Keep scenes already rendered in the output folder.
    pub reuse: bool,
    /// The default `[dense]` settings instead of `DenseConfig::quick`'s.
    pub full_dense: bool,
    /// A Python with pycolmap: COLMAP 4's mappers on the same matches after the align stage.
    pub colmap: Option<PathBuf>,
    /// `[align] mapper` of every block.
    pub mapper: MapperConfig,
    /// Up to this N, the align stage also runs with the other mapper on the same matches (in a
    /// sibling project), timed and scored alike.
    pub compare_mappers_up_to: usize,
}

/// The stages timed, in order: all but the report, which only gathers.
fn timed_stages() -> impl Iterator<Item = Stage> {
    Stage::ALL.into_iter().filter(|s| *s != Stage::Report)
}

/// One stage at one N.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
struct StageCost {
    stage: String,
    wall_s: f64,
    cpu_s: f64,
    peak_mib: f64,
    /// Files under `work/` and `out/` the stage created or changed.
    files: usize,
    /// Killed at the stage limit.
    killed: bool,
    /// Ended with an error (the summary says which).
    failed: bool,
    /// The stage's summary line (`work/run.json`), or its error.
    summary: String,
}

impl StageCost {
    /// Ran to its end: its figures are the stage's whole cost.
    fn completed(&self) -> bool {
        !self.killed && !self.failed
    }
}

/// The align stage with one mapper on a block's matches.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
struct MapperRow {
    mapper: String,
    align: StageCost,
    /// Per epoch: check-point RMSE (dE, dN, dH), GSD.
    check_rmse_gsd: Vec<(String, Option<[f64; 3]>)>,
}

/// One DoD (an epoch against the reference epoch) against the true DoD over the true stable
/// ground.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
struct DodError {
    pair: String,
    cells: usize,
    median_gsd: f64,
    tilt_mm_per_m: f64,
}

/// Everything measured at one N.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
struct SizeRow {
    images: usize,
    epochs: usize,
    gsd_m: f64,
    render_s: f64,
    stages: Vec<StageCost>,
    /// Per epoch: check-point RMSE (dE, dN, dH), GSD.
    check_rmse_gsd: Vec<(String, Option<[f64; 3]>)>,
    dods: Vec<DodError>,
    /// timesift's block and COLMAP's on the same matches, scored alike.
    peers: Vec<PeerRow>,
    /// The align stage with each mapper on the same matches (up to
    /// [`ScaleBench::compare_mappers_up_to`]).
    #[serde(default)]
    mappers: Vec<MapperRow>,
}

pub fn run(bench: &ScaleBench) -> anyhow::Result<()> {
    std::fs::create_dir_all(&bench.out).with_context(|| bench.out.display().to_string())?;
    // With --reuse, the sizes an earlier run measured and this one does not stay in the tables.
    let mut rows: Vec<SizeRow> = if bench.reuse {
        std::fs::read_to_string(bench.out.join("scale.json"))
            .ok()
            .and_then(|text| serde_json::from_str::<Vec<SizeRow>>(&text).ok())
            .unwrap_or_default()
            .into_iter()
            .filter(|r| !bench.sizes.contains(&r.images))
            .collect()
    } else {
        Vec::new()
    };
    for &n in &bench.sizes {
        let row = run_size(bench, n)?;
        println!("{}", table(std::slice::from_ref(&row)));
        rows.push(row);
        rows.sort_by_key(|r| r.images);
        // Written after every size, so that a long run shows what it has.
        write_outputs(bench, &rows)?;
    }
    println!("{}", markdown(bench, &rows));
    println!(
        "written: {}",
        bench.out.join("scale.{md,json,png}").display()
    );
    Ok(())
}

fn write_outputs(bench: &ScaleBench, rows: &[SizeRow]) -> anyhow::Result<()> {
    std::fs::write(bench.out.join("scale.md"), markdown(bench, rows))?;
    std::fs::write(
        bench.out.join("scale.json"),
        serde_json::to_string_pretty(rows)?,
    )?;
    if let Err(e) = plot(rows, &bench.out.join("scale.png")) {
        println!("no plot: {e:#}");
    }
    Ok(())
}

fn run_size(bench: &ScaleBench, n: usize) -> anyhow::Result<SizeRow> {
    let layout = timesift_synth::scenes::ScaleLayout::of(n)?;
    let name = format!("scale-{}", layout.images());
    let dir = bench.out.join(&name);
    let start = Instant::now();
    if !(bench.reuse && dir.join("project.toml").is_file()) {
        let _ = std::fs::remove_dir_all(&dir);
        let spec =
            timesift_synth::scenes::build(&name, timesift_synth::scenes::Scale::Small, bench.seed)?;
        timesift_synth::writer::write_scene(
            &spec,
            &dir,
            &timesift_synth::writer::WriteOptions { images: true },
        )?;
        if !bench.full_dense {
            let mut text = std::fs::read_to_string(dir.join("project.toml"))?;
            text.push_str(&quick_dense_table()?);
            std::fs::write(dir.join("project.toml"), text)?;
        }
    }
    set_mapper(&dir, bench.mapper)?;
    let render_s = start.elapsed().as_secs_f64();
    println!(
        "{name}: {} epochs, rendered in {render_s:.0} s",
        layout.epochs
    );
    for sub in ["work", "out"] {
        let _ = std::fs::remove_dir_all(dir.join(sub));
    }
    let mut stages = Vec::new();
    for stage in timed_stages() {
        let cost = run_stage(bench, &dir, stage)?;
        println!(
            "  {:<8} {:>8.1} s wall {:>8.1} s CPU {:>7.0} MiB {:>6} files  {}",
            cost.stage, cost.wall_s, cost.cpu_s, cost.peak_mib, cost.files, cost.summary
        );
        let stop = !cost.completed();
        stages.push(cost);
        if stop {
            break;
        }
    }
    let project = Project::load(&dir)?;
    let done = |s: Stage| stages.iter().any(|c| c.stage == s.name() && c.completed());
    let truth = timesift::eval::project_truth(&project)?;
    let gsd_m = nadir_gsd(&project)?;
    let check_rmse_gsd = if done(Stage::Align) {
        check_errors(&project, &truth, gsd_m)?
    } else {
        Vec::new()
    };
    let mut mappers = Vec::new();
    if done(Stage::Align) && n <= bench.compare_mappers_up_to {
        let align = stages.iter().find(|c| c.stage == Stage::Align.name());
        mappers.push(MapperRow {
            mapper: mapper_name(bench.mapper).into(),
            align: align.cloned().context("the align stage's cost")?,
            check_rmse_gsd: check_rmse_gsd.clone(),
        });
        mappers.push(other_mapper(bench, &dir, &truth, gsd_m)?);
    }
    let peers = match (&bench.colmap, done(Stage::Align)) {
        (Some(python), true) => crate::bench_scale_colmap::run_peers(&dir, python, bench.threads)
            .unwrap_or_else(|e| {
                vec![PeerRow {
                    mapper: "colmap".into(),
                    error: Some(format!("{e:#}")),
                    ..Default::default()
                }]
            }),
        _ => Vec::new(),
    };
    let dods = if done(Stage::Dem) {
        dod_errors(&project, gsd_m)?
    } else {
        Vec::new()
    };
    Ok(SizeRow {
        images: layout.images(),
        epochs: layout.epochs,
        gsd_m,
        render_s,
        stages,
        check_rmse_gsd,
        dods,
        peers,
        mappers,
    })
}

/// Check-point RMSE per epoch (dE, dN, dH in GSD) of a block oriented by hand.
pub fn score_align(dir: &Path) -> anyhow::Result<Vec<(String, Option<[f64; 3]>)>> {
    let project = Project::load(dir)?;
    let truth = timesift::eval::project_truth(&project)?;
    check_errors(&project, &truth, nadir_gsd(&project)?)
}

/// Per epoch of an oriented project: check-point RMSE (dE, dN, dH) in GSD.
fn check_errors(
    project: &Project,
    truth: &timesift_eval::ProjectTruth<'_>,
    gsd_m: f64,
) -> anyhow::Result<Vec<(String, Option<[f64; 3]>)>> {
    let layout_out = project.layout().out_dir();
    let epochs = timesift::eval::oriented_epochs(&layout_out)?;
    Ok(
        timesift_eval::accuracy::epoch_accuracy(truth, &epochs, &layout_out, gsd_m)?
            .into_iter()
            .map(|a| (a.epoch, a.check_rmse_gsd))
            .collect(),
    )
}

fn mapper_name(mapper: MapperConfig) -> &'static str {
    match mapper {
        MapperConfig::Incremental => "incremental",
        MapperConfig::Global => "global",
        MapperConfig::Auto => "auto",
    }
}

/// Writes `[align] mapper` into a project file (replacing any given).
fn set_mapper(dir: &Path, mapper: MapperConfig) -> anyhow::Result<()> {
    let path = dir.join("project.toml");
    let text = std::fs::read_to_string(&path).with_context(|| path.display().to_string())?;
    let mut lines: Vec<String> = text
        .lines()
        .filter(|l| !l.trim_start().starts_with("mapper ="))
        .map(str::to_string)
        .collect();
    let align = lines
        .iter()
        .position(|l| l.trim() == "[align]")
        .with_context(|| format!("{}: no [align] table", path.display()))?;
    lines.insert(align + 1, format!("mapper = \"{}\"", mapper_name(mapper)));
    std::fs::write(&path, lines.join("\n") + "\n")?;
    Ok(())
}

/// The align stage with the other mapper in a sibling project on the same images, features and
/// matches (linked, not copied), scored like the block's own.
fn other_mapper(
    bench: &ScaleBench,
    dir: &Path,
    truth: &timesift_eval::ProjectTruth<'_>,
    gsd_m: f64,
) -> anyhow::Result<MapperRow> {
    let other = match bench.mapper {
        MapperConfig::Incremental => MapperConfig::Global,
        MapperConfig::Global | MapperConfig::Auto => MapperConfig::Incremental,
    };
    let name = dir.file_name().context("block folder")?.to_string_lossy();
    let sibling = dir.with_file_name(format!("{name}-{}", mapper_name(other)));
    let _ = std::fs::remove_dir_all(&sibling);
    std::fs::create_dir_all(sibling.join("work"))?;
    for entry in std::fs::read_dir(dir)?.flatten() {
        let file = entry.file_name();
        let target = sibling.join(&file);
        match file.to_str() {
            Some("work" | "out") => {}
            Some("images" | "truth") => std::os::unix::fs::symlink(entry.path(), target)?,
            _ if entry.path().is_file() => {
                std::fs::copy(entry.path(), target)?;
            }
            _ => std::os::unix::fs::symlink(entry.path(), target)?,
        }
    }
    for sub in ["features", "matches"] {
        link_tree(&dir.join("work").join(sub), &sibling.join("work").join(sub))?;
    }
    std::fs::copy(dir.join("work/run.json"), sibling.join("work/run.json"))?;
    set_mapper(&sibling, other)?;
    let align = run_stage(bench, &sibling, Stage::Align)?;
    println!(
        "  align ({}) {:>8.1} s wall {:>8.1} s CPU {:>7.0} MiB  {}",
        mapper_name(other),
        align.wall_s,
        align.cpu_s,
        align.peak_mib,
        align.summary
    );
    let check_rmse_gsd = if align.completed() {
        check_errors(&Project::load(&sibling)?, truth, gsd_m)?
    } else {
        Vec::new()
    };
    Ok(MapperRow {
        mapper: mapper_name(other).into(),
        align,
        check_rmse_gsd,
    })
}

/// Hard links of every file under `from` at the same place under `to`.
fn link_tree(from: &Path, to: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(to)?;
    for entry in std::fs::read_dir(from)
        .with_context(|| from.display().to_string())?
        .flatten()
    {
        let target = to.join(entry.file_name());
        if entry.file_type()?.is_dir() {
            link_tree(&entry.path(), &target)?;
        } else {
            std::fs::hard_link(entry.path(), &target)
                .with_context(|| target.display().to_string())?;
        }
    }
    Ok(())
}

/// `[dense]` with [`DenseConfig::quick`]'s settings, to append to a project file.
fn quick_dense_table() -> anyhow::Result<String> {
    Ok(format!(
        "\n[dense]\n{}",
        toml::to_string(&DenseConfig::quick())?
    ))
}

/// The mean ground sampling distance of the true cameras: each one's height above the true
/// surface under it over its focal length (the check points' distance would grow with the
/// block's area).
fn nadir_gsd(project: &Project) -> anyhow::Result<f64> {
    let layout = project.layout();
    let cameras = timesift_io::cameras_json::read_cameras_json(&layout.truth_cameras())?;
    let reference = &project.epochs[project.reference_epoch.index()].name;
    let ground = timesift_eval::products::true_dem(&layout, reference)?;
    let mut gsd = Vec::new();
    for image in &cameras.images {
        let (Some(pose), Some(camera)) = (image.pose, cameras.cameras.get(&image.camera)) else {
            continue;
        };
        let c = pose.center();
        let z = ground.bilinear(c.x, c.y);
        if z.is_finite() {
            gsd.push((c.z - z) / timesift_eval::true_scene::focal(camera));
        }
    }
    anyhow::ensure!(!gsd.is_empty(), "no true camera above the true surface");
    Ok(gsd.iter().sum::<f64>() / gsd.len() as f64)
}

/// Runs one stage of the project in `dir` as a process of its own.
fn run_stage(bench: &ScaleBench, dir: &Path, stage: Stage) -> anyhow::Result<StageCost> {
    let before = file_stamps(dir);
    let mut command = Command::new(std::env::current_exe()?);
    command
        .arg("run-stage")
        .arg(dir)
        .arg(stage.name())
        .env("RAYON_NUM_THREADS", bench.threads.to_string());
    let timed = time_command_within(&mut command, bench.threads, Some(bench.stage_limit));
    let after = file_stamps(dir);
    let files = after
        .iter()
        .filter(|(path, stamp)| before.get(*path) != Some(stamp))
        .count();
    let (run, killed, failed, summary) = match timed {
        Ok((run, true)) => (
            run,
            true,
            false,
            format!("killed after {:.0} s", bench.stage_limit.as_secs_f64()),
        ),
        Ok((run, false)) => (run, false, false, stage_summary(dir, stage)),
        Err(e) => (Default::default(), false, true, format!("failed: {e:#}")),
    };
    Ok(StageCost {
        stage: stage.name().to_string(),
        wall_s: run.wall,
        cpu_s: run.cpu,
        peak_mib: run.peak_mib,
        files,
        killed,
        failed,
        summary,
    })
}

/// The stage's summary in `work/run.json`.
fn stage_summary(dir: &Path, stage: Stage) -> String {
    let text = std::fs::read_to_string(dir.join("work/run.json")).unwrap_or_default();
    serde_json::from_str::<serde_json::Value>(&text)
        .ok()
        .and_then(|v| {
            v["stages"][stage.name()]["summary"]
                .as_str()
                .map(str::to_string)
        })
        .unwrap_or_default()
}

/// Size and modification time of every file under `dir/work` and `dir/out`.
fn file_stamps(dir: &Path) -> BTreeMap<PathBuf, (u64, SystemTime)> {
    let mut stamps = BTreeMap::new();
    let mut stack = vec![dir.join("work"), dir.join("out")];
    while let Some(d) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        for entry in entries.flatten() {
            let path = entry.path();
            let Ok(meta) = entry.metadata() else { continue };
            if meta.is_dir() {
                stack.push(path);
            } else if let Ok(modified) = meta.modified() {
                stamps.insert(path, (meta.len(), modified));
            }
        }
    }
    stamps
}

/// Each later epoch's DoD against the reference epoch's, minus the true DoD, over the cells of
/// the true stable ground both DEMs measured: median (GSD) and tilt of the plane through it.
fn dod_errors(project: &Project, gsd_m: f64) -> anyhow::Result<Vec<DodError>> {
    let layout = project.layout();
    let stable = Dem::from_raster(
        timesift_io::geotiff::read_f32(&layout.truth_dir().join("stable.tif"))?,
        None,
    )?;
    type CellErrors = BTreeMap<(i64, i64), (f64, f64, f64)>;
    let errors = |epoch: &str| -> anyhow::Result<CellErrors> {
        let truth = timesift_eval::products::true_dem(&layout, epoch)?;
        let dem = timesift_io::geotiff::read_f32(&layout.dem(epoch))?;
        let count = timesift_io::geotiff::read_f32(&layout.dem_count(epoch))?;
        let cell = dem.georef.transform.pixel_width;
        Ok(
            timesift_eval::products::dem_height_error_points(&dem, &count, &truth, |x, y| {
                stable.bilinear(x, y) > 0.99
            })
            .into_iter()
            .map(|p| {
                (
                    ((p.0 / cell).floor() as i64, (p.1 / cell).floor() as i64),
                    p,
                )
            })
            .collect(),
        )
    };
    let reference = &project.epochs[project.reference_epoch.index()].name;
    let at_reference = errors(reference)?;
    let mut dods = Vec::new();
    for epoch in &project.epochs {
        if &epoch.name == reference {
            continue;
        }
        let points: Vec<(f64, f64, f64)> = errors(&epoch.name)?
            .into_iter()
            .filter_map(|(key, (x, y, e))| at_reference.get(&key).map(|r| (x, y, e - r.2)))
            .collect();
        if let Some(SurfaceAgreement {
            count,
            median_m,
            tilt_mm_per_m,
            ..
        }) = residual_plane(&points)
        {
            dods.push(DodError {
                pair: format!("{reference}__{}", epoch.name),
                cells: count,
                median_gsd: median_m / gsd_m,
                tilt_mm_per_m,
            });
        }
    }
    Ok(dods)
}

/// The slope of log `seconds` against log `images` by least squares over the sizes from
/// `from` images on (`None` with fewer than two).
fn growth_exponent(points: &[(usize, f64)], from: usize) -> Option<f64> {
    let logs: Vec<(f64, f64)> = points
        .iter()
        .filter(|(n, s)| *n >= from && *s > 0.0)
        .map(|(n, s)| ((*n as f64).ln(), s.ln()))
        .collect();
    if logs.len() < 2 {
        return None;
    }
    let m = logs.len() as f64;
    let (mx, my) = (
        logs.iter().map(|p| p.0).sum::<f64>() / m,
        logs.iter().map(|p| p.1).sum::<f64>() / m,
    );
    let sxx: f64 = logs.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = logs.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    (sxx > 0.0).then(|| sxy / sxx)
}

/// Wall seconds of `stage` at each size where it ran to its end.
fn stage_walls(rows: &[SizeRow], stage: &str) -> Vec<(usize, f64)> {
    rows.iter()
        .filter_map(|r| {
            let c = r.stages.iter().find(|c| c.stage == stage)?;
            c.completed().then_some((r.images, c.wall_s))
        })
        .collect()
}

fn table(rows: &[SizeRow]) -> String {
    let mut s = String::from(
        "| N | epochs | stage | wall s | CPU s | peak MiB | files | summary |\n|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        for c in &r.stages {
            s.push_str(&format!(
                "| {} | {} | {} | {:.1} | {:.1} | {:.0} | {} | {} |\n",
                r.images, r.epochs, c.stage, c.wall_s, c.cpu_s, c.peak_mib, c.files, c.summary
            ));
        }
    }
    s
}

fn markdown(bench: &ScaleBench, rows: &[SizeRow]) -> String {
    let mut s = format!(
        "Scale bench: `synth scale-N`, seed {}, {} threads per stage, stage limit {:.0} s, [dense] {}.\n\n",
        bench.seed,
        bench.threads,
        bench.stage_limit.as_secs_f64(),
        if bench.full_dense {
            "defaults".to_string()
        } else {
            format!("quick: {}", DenseConfig::quick().differences())
        }
    );
    s.push_str(&table(rows));
    s.push_str("\n## Images to oriented block (features + match + align), wall s\n\n| N | s |\n|---|---|\n");
    for r in rows {
        let walls: Vec<&StageCost> = r
            .stages
            .iter()
            .filter(|c| ["features", "match", "align"].contains(&c.stage.as_str()))
            .collect();
        if walls.len() == 3 && walls.iter().all(|c| c.completed()) {
            s.push_str(&format!(
                "| {} | {:.0} |\n",
                r.images,
                walls.iter().map(|c| c.wall_s).sum::<f64>()
            ));
        }
    }
    s.push_str("\n## Growth exponents (slope of log wall time against log N, N ≥ 200)\n\n| stage | exponent | sizes |\n|---|---|---|\n");
    for stage in timed_stages() {
        let walls = stage_walls(rows, stage.name());
        let used = walls.iter().filter(|(n, _)| *n >= 200).count();
        s.push_str(&format!(
            "| {} | {} | {used} |\n",
            stage.name(),
            growth_exponent(&walls, 200).map_or("—".to_string(), |e| format!("{e:.2}"))
        ));
    }
    s.push_str("\n## Accuracy per N: check-point RMSE (worst epoch, GSD) and DoD − true DoD on stable ground (worst pair)\n\n| N | GSD m | check dE | dN | dH | DoD median GSD | DoD tilt mm/m |\n|---|---|---|---|---|---|---|\n");
    for r in rows {
        let worst = |k: usize| {
            r.check_rmse_gsd
                .iter()
                .filter_map(|(_, c)| c.map(|c| c[k]))
                .fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.max(v))))
        };
        let cell = |v: Option<f64>, d: usize| v.map_or("—".to_string(), |v| format!("{v:.d$}"));
        let dod_median = r
            .dods
            .iter()
            .map(|d| d.median_gsd)
            .max_by(|a, b| a.abs().total_cmp(&b.abs()));
        let dod_tilt = r
            .dods
            .iter()
            .map(|d| d.tilt_mm_per_m)
            .max_by(f64::total_cmp);
        s.push_str(&format!(
            "| {} | {:.3} | {} | {} | {} | {} | {} |\n",
            r.images,
            r.gsd_m,
            cell(worst(0), 2),
            cell(worst(1), 2),
            cell(worst(2), 2),
            cell(dod_median, 3),
            cell(dod_tilt, 2)
        ));
    }
    if rows.iter().any(|r| !r.mappers.is_empty()) {
        s.push_str(&mapper_table(rows));
    }
    if rows.iter().any(|r| !r.peers.is_empty()) {
        s.push_str(&peer_table(rows));
    }
    s
}

/// The align stage with each mapper on the same matches.
fn mapper_table(rows: &[SizeRow]) -> String {
    let mut s = String::from(
        "\n## The align stage with each mapper on the same matches\n\n\
         | N | mapper | wall s | CPU s | peak MiB | checks dE / dN / dH per epoch (GSD) |\n|---|---|---|---|---|---|\n",
    );
    for r in rows {
        for m in &r.mappers {
            let checks: Vec<String> = m
                .check_rmse_gsd
                .iter()
                .map(|(_, c)| {
                    c.map_or("—".into(), |c| {
                        format!("{:.2}/{:.2}/{:.2}", c[0], c[1], c[2])
                    })
                })
                .collect();
            s.push_str(&format!(
                "| {} | {} | {:.1} | {:.1} | {:.0} | {} |\n",
                r.images,
                m.mapper,
                m.align.wall_s,
                m.align.cpu_s,
                m.align.peak_mib,
                checks.join(", ")
            ));
        }
    }
    s
}

/// timesift's align stage against COLMAP 4's mappers on the same verified matches.
fn peer_table(rows: &[SizeRow]) -> String {
    let mut s = String::from(
        "\n## Orientation against COLMAP 4 (pycolmap) on the same verified matches\n\n\
         Every block scored alike: a similarity to the GNSS priors, or to the GCPs intersected \
         from their markers; each check point intersected per epoch; RMSE dE/dN/dH in GSD.\n\n\
         | N | mapper | wall s | time / timesift's align | images | checks, GNSS similarity (GSD) | checks, GCP similarity (GSD) |\n|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let align = r
            .stages
            .iter()
            .find(|c| c.stage == "align" && c.completed())
            .map(|c| c.wall_s);
        let gsd = |v: Option<[f64; 3]>| {
            v.map_or("—".to_string(), |v| {
                format!(
                    "{:.2} / {:.2} / {:.2}",
                    v[0] / r.gsd_m,
                    v[1] / r.gsd_m,
                    v[2] / r.gsd_m
                )
            })
        };
        for p in &r.peers {
            let seconds = if p.mapper == "timesift" {
                align
            } else {
                p.seconds
            };
            let ratio = match (seconds, align) {
                (Some(t), Some(a)) if a > 0.0 => format!("{:.2}", t / a),
                _ => "—".to_string(),
            };
            s.push_str(&format!(
                "| {} | {} | {} | {ratio} | {} | {} | {} |{}\n",
                r.images,
                p.mapper,
                seconds.map_or("—".to_string(), |t| format!("{t:.1}")),
                p.registered.map_or("—".to_string(), |n| n.to_string()),
                gsd(p.check_rmse_gnss_m),
                gsd(p.check_rmse_gcps_m),
                p.error.as_ref().map_or(String::new(), |e| format!(" {e}"))
            ));
        }
    }
    s
}

/// Wall time per stage against N, both axes logarithmic.
fn plot(rows: &[SizeRow], path: &Path) -> anyhow::Result<()> {
    use plotters::prelude::*;
    crate::register_plot_font()?;
    let series: Vec<(&str, Vec<(f64, f64)>)> = timed_stages()
        .map(|s| {
            (
                s.name(),
                stage_walls(rows, s.name())
                    .into_iter()
                    .map(|(n, t)| (n as f64, t.max(0.01)))
                    .collect(),
            )
        })
        .collect();
    let all: Vec<(f64, f64)> = series.iter().flat_map(|s| s.1.iter().copied()).collect();
    anyhow::ensure!(!all.is_empty(), "no stage ran to its end");
    let (x0, x1) = all
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.0), b.max(p.0)));
    let (y0, y1) = all
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
    const SIZE: (u32, u32) = (900, 620);
    let mut pixels = vec![0u8; (SIZE.0 * SIZE.1 * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, SIZE).into_drawing_area();
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                "timesift: wall time per stage against block size (2 threads)",
                ("sans-serif", 20),
            )
            .margin(16)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(
                (x0 * 0.8..x1 * 1.25).log_scale(),
                (y0 * 0.5..y1 * 2.0).log_scale(),
            )?;
        chart
            .configure_mesh()
            .x_desc("images in the block")
            .y_desc("wall seconds")
            .draw()?;
        for (k, (name, points)) in series.iter().enumerate() {
            let colour = Palette99::pick(k).to_rgba();
            chart
                .draw_series(LineSeries::new(points.clone(), colour.stroke_width(2)))?
                .label(*name)
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
                });
            chart.draw_series(points.iter().map(|p| Circle::new(*p, 3, colour.filled())))?;
        }
        chart
            .configure_series_labels()
            .border_style(BLACK)
            .background_style(WHITE.mix(0.9))
            .position(SeriesLabelPosition::UpperLeft)
            .draw()?;
        root.present()?;
    }
    // plotters' own PNG encoder would bring a second `image`; the workspace's writes it.
    image::RgbImage::from_raw(SIZE.0, SIZE.1, pixels)
        .context("plot buffer size")?
        .save(path)
        .with_context(|| path.display().to_string())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_quick_dense_table_reads_back_as_the_quick_settings() {
        #[derive(serde::Deserialize)]
        struct File {
            dense: DenseConfig,
        }
        let file: File = toml::from_str(&quick_dense_table().unwrap()).unwrap();
        assert_eq!(file.dense, DenseConfig::quick());
    }

    #[test]
    fn the_growth_exponent_of_a_power_law_is_its_power() {
        let points: Vec<(usize, f64)> = [100, 200, 400, 800, 1600]
            .iter()
            .map(|&n| (n, 0.3 * (n as f64).powf(1.25)))
            .collect();
        let e = growth_exponent(&points, 200).unwrap();
        assert!((e - 1.25).abs() < 1e-9, "{e}");
        assert!(growth_exponent(&points[..2], 200).is_none());
    }
}
