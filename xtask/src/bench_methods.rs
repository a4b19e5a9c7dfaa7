//! `cargo xtask bench-methods`: every `synth` scene × every co-registration strategy. Each scene
//! is rendered once and its features and matches computed once (they do not depend on the
//! strategy); then the `align` stage runs per strategy and is compared with the truth: per
//! strategy and epoch, images oriented, check-point RMSE (dE, dN, dH) in metres and in ground
//! sampling distances, camera-centre RMSE, reprojection RMS, inter-epoch tie points, the
//! disagreement of check points between each epoch and the reference epoch, and wall time.
//! Then, per strategy, the products users look at: the dense, dem and change stages on that
//! orientation, and between consecutive epochs the stable-area DoD (mean, median, and the gain of
//! its plane across the stable area — a tilt check points along a corridor cannot see) and the
//! volume change of every region of `truth/change.json` against the true volume.
//! Written as `methods.md` and `methods.json` in the output folder and printed.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use timesift::Project;
use timesift::commands::compare::DemReport;
use timesift::config::DenseConfig;
use timesift::eval::{oriented_epochs, project_truth};
use timesift::report::read_json;
use timesift::stages::{Stage, run, run_stage};
use timesift_align::Method;
use timesift_eval::accuracy::{EpochAccuracy, epoch_accuracy, ground_sampling_distance};
use timesift_eval::products::region_volumes;
use timesift_eval::triple;

/// What to run.
pub struct MethodsBench {
    pub scenes: Vec<String>,
    pub methods: Vec<Method>,
    pub scale: String,
    /// Seeds of the scenes: each scene is rendered and run once per seed (rows named
    /// `scene#seed` when there are several), and the reference-epoch table pools them.
    pub seeds: Vec<u64>,
    pub out: PathBuf,
    /// Run dense, dem and change per strategy and score the products.
    pub products: bool,
    /// The default `[dense]` settings instead of the demo's lighter ones
    /// (`DenseConfig::quick`): the strategies differ in orientation, which both show.
    pub full_dense: bool,
    /// Which inter-epoch ties the single-block strategies keep, one run per entry (rows named
    /// `method+ties` beyond the first): `default` (the project's: stable areas when given),
    /// `all`, `plain` (every tie and no GNSS offsets: the single block before they existed),
    /// `before` (`plain` with one outlier bound for the whole block: the single block as issue
    /// 22 found it; without offsets no flight is weighed by its scatter),
    /// `pooled` (the project's ties, one observation outlier bound for the whole block instead
    /// of each camera group's own), or `auto-blind` (the regional change detection, the stable
    /// areas hidden from the align stage; the products are still judged on them), or
    /// `joined` (the project's ties and a second look for inter-epoch ties by descriptor,
    /// `[align] join_epoch_ties = true`), or `auto-blind-nosurface` (`auto-blind` without surface
    /// ties), or `nosurface` (no surface ties,
    /// `[align] surface_ties = false`: as before they existed), or `refgnss` (the GNSS priors of the reference epoch
    /// only: whether the other epochs' priors move the reference epoch's datum), or
    /// `scatter-all` (every flight's GNSS priors weighed by their scatter about their offset,
    /// `[gnss] weigh_by_scatter = "all"`, as before the default became the controlled flights),
    /// or `refdem` (no control, a photo index and a reference DEM:
    /// [`without_control_on_a_reference_dem`]).
    pub ties: Vec<String>,
}

/// The align stage's view of the project for one `--ties` entry.
fn with_ties(mut project: Project, ties: &str) -> anyhow::Result<Project> {
    use timesift::config::{InterEpochTies, OutlierBoundConfig};
    match ties {
        "default" => {}
        "all" => project.config.align.inter_epoch_ties = InterEpochTies::All,
        "plain" | "before" => {
            project.config.align.inter_epoch_ties = InterEpochTies::All;
            project.config.gnss.offsets = timesift::config::GnssOffsets::None;
            if ties == "before" {
                project.config.align.outlier_bound = OutlierBoundConfig::Pooled;
            }
        }
        "pooled" => project.config.align.outlier_bound = OutlierBoundConfig::Pooled,
        "joined" => project.config.align.join_epoch_ties = true,
        "nosurface" => project.config.align.surface_ties = false,
        cal if cal.starts_with("cal:") => {
            // `cal:k1+b1+b2`: the intrinsics the final adjustments estimate; `cal:none` fixes all.
            let names = &cal["cal:".len()..];
            project.config.align.self_calibration = Some(match names {
                "none" => Vec::new(),
                _ => names.split('+').map(str::to_string).collect(),
            });
        }
        "scatter-all" => {
            project.config.gnss.weigh_by_scatter = timesift::config::WeighByScatter::All
        }
        "refgnss" => {
            // By image name, as gnss.csv names them.
            let r = project.reference_epoch;
            let keep: std::collections::HashSet<String> = project
                .images
                .iter()
                .filter(|i| i.epoch == r)
                .map(|i| i.name.clone())
                .collect();
            project.gnss.retain(|g| keep.contains(&g.image));
        }
        "refdem" => without_control_on_a_reference_dem(&mut project)?,
        "auto-blind" | "auto-blind-nosurface" => {
            project.config.align.inter_epoch_ties = InterEpochTies::Auto;
            project.stable_areas.clear();
            project.config.align.surface_ties = ties == "auto-blind";
        }
        other => {
            anyhow::bail!(
                "--ties: unknown \"{other}\" (default, all, plain, before, pooled, auto-blind, auto-blind-nosurface, joined, nosurface, refgnss, scatter-all, cal:NAME+NAME…, cal:none, refdem)"
            )
        }
    }
    Ok(project)
}

/// σ of the camera centres a photo index gives (each coordinate), metres: `refdem`'s datum to
/// start from.
const PHOTO_INDEX_SIGMA: f64 = 20.0;
/// The noise of `refdem`'s reference DEM, ground sampling distances, and its vertical shift,
/// metres (issue 48: a modern DEM that is neither exact nor in the scene's datum).
const REFERENCE_DEM_NOISE_GSD: f64 = 0.3;
const REFERENCE_DEM_SHIFT_M: f64 = 0.5;
/// Where `refdem` writes its reference DEM, in the scene's folder.
const REFERENCE_DEM_FILE: &str = "reference_dem.tif";

/// `--ties refdem`: no control point; camera centres from a photo index (the true ones with
/// [`PHOTO_INDEX_SIGMA`] of noise, stated so); and a reference DEM: the last epoch's true
/// surface with [`REFERENCE_DEM_NOISE_GSD`] of noise and [`REFERENCE_DEM_SHIFT_M`] added,
/// `[align] reference_dem`, its σ the noise's.
fn without_control_on_a_reference_dem(project: &mut Project) -> anyhow::Result<()> {
    let gsd = ground_sampling_distance(&project_truth(project)?)?;
    let truth_dir = project.layout().truth_dir();
    let truth = timesift_io::cameras_json::read_cameras_json(&truth_dir.join("cameras.json"))?;
    let mut rng = timesift_core::SeededRng::new(48);
    let control: std::collections::HashSet<String> =
        project.gcps.drain(..).map(|g| g.name).collect();
    project.markers.retain(|m| !control.contains(&m.name));
    project.gnss = truth
        .images
        .iter()
        .filter_map(|im| {
            let centre = im.pose?.center();
            let mut noise = || PHOTO_INDEX_SIGMA * rng.normal();
            let position = centre + nalgebra::Vector3::new(noise(), noise(), noise());
            Some(timesift_io::csv_inputs::GnssPrior {
                image: im.name.clone(),
                position,
                sigma: Some((PHOTO_INDEX_SIGMA, PHOTO_INDEX_SIGMA)),
                line: 0,
            })
        })
        .collect();
    let last = project
        .epochs
        .last()
        .map(|e| e.name.clone())
        .context("a scene without epochs")?;
    let mut dem = timesift_io::geotiff::read_f32(&truth_dir.join(format!("dem_{last}.tif")))?;
    let nodata = dem.georef.nodata;
    for h in dem.data.iter_mut() {
        if h.is_finite() && nodata != Some(f64::from(*h)) {
            *h += (REFERENCE_DEM_SHIFT_M + REFERENCE_DEM_NOISE_GSD * gsd * rng.normal()) as f32;
        }
    }
    timesift_io::geotiff::write_f32(&project.dir.join(REFERENCE_DEM_FILE), &dem)?;
    project.config.align.reference_dem = Some(REFERENCE_DEM_FILE.into());
    project.config.align.reference_dem_sigma = REFERENCE_DEM_NOISE_GSD * gsd;
    Ok(())
}

/// One epoch's DEM against the reference DEM over the true stable ground (`--ties refdem`).
#[derive(Debug, Clone, serde::Serialize)]
struct AgainstReference {
    epoch: String,
    cells: usize,
    median_m: f64,
    median_gsd: f64,
    tilt_mm_per_m: f64,
}

/// Every epoch's DEM against `reference` over `truth/stable.tif`: median and the tilt of the
/// plane through the differences.
fn against_reference(
    project: &Project,
    reference: &Path,
    gsd: f64,
) -> anyhow::Result<Vec<AgainstReference>> {
    use timesift_change::grid::Dem;
    let layout = project.layout();
    let reference = Dem::from_raster(timesift_io::geotiff::read_f32(reference)?, None)?;
    let stable = Dem::from_raster(
        timesift_io::geotiff::read_f32(&layout.truth_dir().join("stable.tif"))?,
        None,
    )?;
    let mut rows = Vec::new();
    for epoch in &project.epochs {
        let dem = timesift_io::geotiff::read_f32(&layout.dem(&epoch.name))?;
        let count = timesift_io::geotiff::read_f32(&layout.dem_count(&epoch.name))?;
        let points =
            timesift_eval::products::dem_height_error_points(&dem, &count, &reference, |x, y| {
                stable.bilinear(x, y) > 0.5
            });
        if let Some(plane) = timesift_change::trend::residual_plane(&points) {
            rows.push(AgainstReference {
                epoch: epoch.name.clone(),
                cells: plane.count,
                median_m: plane.median_m,
                median_gsd: plane.median_m / gsd,
                tilt_mm_per_m: plane.tilt_mm_per_m,
            });
        }
    }
    Ok(rows)
}

/// The stable-area DoD of one pair of consecutive epochs, metres.
#[derive(Debug, Clone, serde::Serialize)]
struct PairProduct {
    pair: String,
    stable_mean: f64,
    stable_median: f64,
    plane_gain: Option<f64>,
    lod95: Option<f64>,
}

/// The products of one strategy on one scene.
#[derive(Debug, Clone, serde::Serialize)]
struct ProductRow {
    scene: String,
    method: String,
    /// Per consecutive epoch pair.
    pairs: Vec<PairProduct>,
    /// Σ |measured − true| / Σ |true| over every region and pair of `truth/change.json`.
    volume_relative_error: Option<f64>,
    /// Σ |measured − true| over them, m³.
    volume_abs_error_m3: Option<f64>,
    /// Regions × pairs measured (some cell with a difference) and in `truth/change.json`: the
    /// errors above are over the measured ones.
    regions_measured: (usize, usize),
    /// With `--ties refdem`: every epoch's DEM against the reference DEM over stable ground.
    against_reference: Vec<AgainstReference>,
    seconds: f64,
    error: Option<String>,
}

/// One strategy on one epoch of one scene (or its failure).
#[derive(Debug, Clone, serde::Serialize)]
struct Row {
    scene: String,
    method: String,
    #[serde(flatten)]
    accuracy: Option<EpochAccuracy>,
    seconds: f64,
    error: Option<String>,
}

pub fn run_bench(bench: &MethodsBench) -> anyhow::Result<()> {
    let scale: timesift_synth::scenes::Scale = bench
        .scale
        .parse()
        .map_err(|e: String| anyhow::anyhow!("--scale: {e}"))?;
    std::fs::create_dir_all(&bench.out).with_context(|| bench.out.display().to_string())?;
    let mut rows = Vec::new();
    let mut product_rows = Vec::new();
    let mut tie_rows: Vec<(String, String, timesift::report::EpochPairTies)> = Vec::new();
    let runs = bench.seeds.iter().flat_map(|&seed| {
        bench.scenes.iter().map(move |name| {
            let label = if bench.seeds.len() > 1 {
                format!("{name}#{seed}")
            } else {
                name.clone()
            };
            (name, seed, label)
        })
    });
    for (name, seed, scene) in runs {
        let scene = &scene;
        let dir = bench.out.join(scene);
        let _ = std::fs::remove_dir_all(&dir);
        let spec = timesift_synth::scenes::build(name, scale, seed)?;
        timesift_synth::writer::write_scene(
            &spec,
            &dir,
            &timesift_synth::writer::WriteOptions::default(),
        )?;
        let project = Project::load(&dir)?;
        // The scene's true click σ over the accuracy the project states: see `evaluate`.
        let clicks = spec.marker_sigma / project.config.align.marker_accuracy_px;
        let start = Instant::now();
        run(&project, Some(Stage::Features), Some(Stage::Match))?;
        println!(
            "{scene}: features and matches in {:.1} s",
            start.elapsed().as_secs_f64()
        );
        let gsd = ground_sampling_distance(&project_truth(&project)?)?;
        println!("{scene}: ground sampling distance at the check points {gsd:.4} m");
        let variants = bench.methods.iter().flat_map(|&m| {
            bench.ties.iter().enumerate().map(move |(k, t)| {
                let label = if k == 0 {
                    m.to_string()
                } else {
                    format!("{m}+{t}")
                };
                (m, t.clone(), label)
            })
        });
        for (method, ties, name) in variants {
            let name = &name;
            let mut project = Project::load(&dir)?;
            project.config.align.method = method;
            if !bench.full_dense {
                project.config.dense = DenseConfig::quick();
            }
            let start = Instant::now();
            let result = run_stage(&with_ties(project.clone(), &ties)?, Stage::Align);
            let seconds = start.elapsed().as_secs_f64();
            match result {
                Ok(_) => {
                    if bench.products {
                        let reference =
                            (ties == "refdem").then(|| (dir.join(REFERENCE_DEM_FILE), gsd));
                        product_rows.push(products(scene, name, &project, reference));
                    }
                    let kept = dir.join(format!("out-{name}"));
                    let _ = std::fs::remove_dir_all(&kept);
                    std::fs::rename(dir.join("out"), &kept)?;
                    restore_fiducials(&kept, &dir.join("out"))?;
                    let report: timesift::report::AlignReport =
                        read_json(&kept.join("report.json"))?;
                    tie_rows.extend(
                        report
                            .epoch_pairs
                            .into_iter()
                            .map(|p| (scene.clone(), name.clone(), p)),
                    );
                    rows.extend(evaluate(
                        scene, name, &project, &kept, gsd, seconds, clicks,
                    )?);
                }
                Err(e) => rows.push(Row {
                    scene: scene.clone(),
                    method: name.clone(),
                    accuracy: None,
                    seconds,
                    error: Some(e.to_string()),
                }),
            }
        }
    }
    let mut markdown =
        table(&rows) + &findings(&rows) + &reference_table(&rows) + &tie_table(&tie_rows);
    if bench.products {
        let dense = if bench.full_dense {
            DenseConfig::default()
        } else {
            DenseConfig::quick()
        };
        markdown.push_str(&format!(
            "\nProducts with [dense] {} (--full-dense: the defaults).\n",
            dense.differences()
        ));
        markdown.push_str(&product_table(&product_rows));
    }
    println!("{markdown}");
    std::fs::write(bench.out.join("methods.md"), &markdown)?;
    std::fs::write(
        bench.out.join("methods.json"),
        serde_json::to_string_pretty(&serde_json::json!({
            "orientation": rows,
            "products": product_rows,
        }))?,
    )?;
    println!("written: {}", bench.out.join("methods.{md,json}").display());
    Ok(())
}

/// The reference epoch's check-point height error of every strategy against `independent`'s (the
/// reference epoch oriented alone with its own control): does the rest of the block drag the
/// reference datum? Measured (with the markers' click noise, as a user sees it) and the
/// orientation's own (exact pixels of the check points, [`timesift_eval::accuracy::orientation_check_errors`]).
/// With four check points a scene's ratio varies from seed to seed by more than the 10 % it is
/// judged by, so the rows of one scene run with several seeds (`scene#seed`) are pooled: the
/// ratio of the RMS over the seeds of each run's RMSE (with as many check points in every run,
/// the RMSE over all of them), beside the ratio per seed. The reference
/// is each scene's first epoch, as `synth` writes it.
fn reference_table(rows: &[Row]) -> String {
    let first_epoch = |scene: &str, method: &str| {
        rows.iter()
            .find(|r| r.scene == scene && r.method == method)
            .and_then(|r| r.accuracy.as_ref())
    };
    let dh = |v: Option<[f64; 3]>| v.map(|v| v[2]);
    // (measured, orientation alone) of one run.
    type Pair = (Option<f64>, Option<f64>);
    /// One scene (without its seed) and method: per seed the method's pair and `independent`'s.
    struct Group {
        scene: String,
        method: String,
        gnss: bool,
        /// Per seed: the method's pair, `independent`'s, and the method's check dH RMSE from
        /// the markers alone.
        runs: Vec<(Pair, Pair, Option<f64>)>,
    }
    let mut groups: Vec<Group> = Vec::new();
    let mut seen: Vec<(&str, &str)> = Vec::new();
    let independent = Method::Independent.name();
    for r in rows.iter().filter(|r| r.method != independent) {
        if seen.contains(&(r.scene.as_str(), r.method.as_str())) {
            continue;
        }
        seen.push((&r.scene, &r.method));
        let (Some(a), Some(b)) = (
            first_epoch(&r.scene, &r.method),
            first_epoch(&r.scene, independent),
        ) else {
            continue;
        };
        let entry = (
            (dh(a.check_rmse_m), dh(a.orientation_check_rmse_m)),
            (dh(b.check_rmse_m), dh(b.orientation_check_rmse_m)),
            dh(a.check_markers_rmse_m),
        );
        let gnss = a.gnss_offset_error_m.is_some() || b.gnss_offset_error_m.is_some();
        let base = r.scene.split('#').next().unwrap_or(&r.scene);
        match groups
            .iter_mut()
            .find(|g| g.scene == base && g.method == r.method)
        {
            Some(g) => {
                g.gnss |= gnss;
                g.runs.push(entry);
            }
            None => groups.push(Group {
                scene: base.to_string(),
                method: r.method.clone(),
                gnss,
                runs: vec![entry],
            }),
        }
    }
    let ratio = |pairs: &[(Option<f64>, Option<f64>)]| -> (String, String) {
        let both: Vec<(f64, f64)> = pairs.iter().filter_map(|&(x, y)| Some((x?, y?))).collect();
        let each: Vec<String> = both
            .iter()
            .map(|(x, y)| {
                if *y > 0.0 {
                    format!("{:.2}", x / y)
                } else {
                    "–".into()
                }
            })
            .collect();
        let (xs, ys): (Vec<f64>, Vec<f64>) = both.iter().copied().unzip();
        let (Some(x), Some(y)) = (rms(&xs), rms(&ys)) else {
            return ("–".into(), "–".into());
        };
        (
            format!("{x:.3} / {y:.3}"),
            if y > 0.0 {
                format!("{:.2} ({})", x / y, each.join(", "))
            } else {
                "–".into()
            },
        )
    };
    let mut s = String::from(
        "\n## Reference epoch: check dH RMSE (m) against `independent`'s — measured · orientation \
         alone (RMSE over the seeds run; ratio pooled, then per seed), and the method's check dH \
         RMSE from the markers' clicks alone, at the scene's true click σ (the measured figure's \
         floor with a perfect orientation)\n\n| scene | GNSS | method | seeds | measured | ratio | orientation alone | \
         ratio | markers alone |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    for Group {
        scene,
        method,
        gnss,
        runs,
    } in &groups
    {
        let markers: Vec<f64> = runs.iter().filter_map(|r| r.2).collect();
        let markers = rms(&markers).map_or("–".into(), |m| format!("{m:.3}"));
        let measured: Vec<Pair> = runs.iter().map(|(a, b, _)| (a.0, b.0)).collect();
        let alone: Vec<Pair> = runs.iter().map(|(a, b, _)| (a.1, b.1)).collect();
        let (m, m_ratio) = ratio(&measured);
        let (o, o_ratio) = ratio(&alone);
        s.push_str(&format!(
            "| {scene} | {} | {method} | {} | {m} | {m_ratio} | {o} | {o_ratio} | {markers} |\n",
            if *gnss { "biased" } else { "none" },
            runs.len(),
        ));
    }
    s
}

/// Root mean square; `None` for no values.
fn rms(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt())
}

/// Per strategy and pair of epochs, the tie points both observe and their spread across and
/// along the block against every tie point's; across, with the points held to the reference
/// epoch's surface too, and against the tie points on the stable areas (where given).
fn tie_table(rows: &[(String, String, timesift::report::EpochPairTies)]) -> String {
    let mut s = String::from(
        "\n## Inter-epoch ties per pair of epochs: count, spread across / along the block (std, m) \
         against all tie points'; across with the points held to the reference epoch's surface \
         (surface ties), and against the tie points on stable ground\n\n| scene | method | pair \
         | ties | across (all) | along (all) | across / all | across, with held | across (stable) \
         | across / stable | with held / stable |\n|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let m = |v: Option<f64>| v.map_or("–".into(), |v| format!("{v:.1}"));
    let ratio = |a: Option<f64>, b: Option<f64>| match (a, b) {
        (Some(a), Some(b)) if b > 0.0 => format!("{:.0} %", 100.0 * a / b),
        _ => "–".into(),
    };
    for (scene, method, p) in rows {
        let all = Some(p.all_across_std_m);
        s.push_str(&format!(
            "| {scene} | {method} | {} → {} | {} | {} ({:.1}) | {} ({:.1}) | {} | {} | {} | {} | {} |\n",
            p.epochs[0],
            p.epochs[1],
            p.ties,
            m(p.across_std_m),
            p.all_across_std_m,
            m(p.along_std_m),
            p.all_along_std_m,
            ratio(p.across_std_m, all),
            m(p.held_across_std_m),
            m(p.stable_across_std_m),
            ratio(p.across_std_m, p.stable_across_std_m),
            ratio(p.held_across_std_m.or(p.across_std_m), p.stable_across_std_m),
        ));
    }
    s
}

/// The fiducials stage's outputs (`out/fiducials*`, made once with the features) put back into
/// `out` after a strategy's outputs moved away: the next strategy's align stage reads the scans'
/// interior orientations from them.
fn restore_fiducials(kept: &Path, out: &Path) -> anyhow::Result<()> {
    for entry in std::fs::read_dir(kept)?.flatten() {
        if entry.file_name().to_string_lossy().starts_with("fiducials") {
            std::fs::create_dir_all(out)?;
            std::fs::copy(entry.path(), out.join(entry.file_name()))?;
        }
    }
    Ok(())
}

/// The rows of one run. `clicks` is the scene's true click σ over the marker accuracy the
/// project states (synth clicks at 0.3 px; the default accuracy is 0.5 px): the report's
/// markers-alone RMSE is at the stated accuracy, the bench's at the true one, so that it is the
/// floor the measured check RMSE actually has.
fn evaluate(
    scene: &str,
    method: &str,
    project: &Project,
    out: &Path,
    gsd: f64,
    seconds: f64,
    clicks: f64,
) -> anyhow::Result<Vec<Row>> {
    Ok(
        epoch_accuracy(&project_truth(project)?, &oriented_epochs(out)?, out, gsd)?
            .into_iter()
            .map(|mut a| {
                a.check_markers_rmse_m = a.check_markers_rmse_m.map(|m| m.map(|v| v * clicks));
                a
            })
            .map(|a| Row {
                scene: scene.to_string(),
                method: method.to_string(),
                accuracy: Some(a),
                seconds,
                error: None,
            })
            .collect(),
    )
}

fn table(rows: &[Row]) -> String {
    let mut s = String::from(
        "| scene | method | epoch | oriented | check RMSE dE/dN/dH (m) | (GSD) \
         | orientation alone at the check points (m) | epoch − ref. (m) | the same, orientation alone (m) | centre RMSE (m) | RMS px | observations | inter-epoch ties | GNSS offset − true bias (m) | (σ) \
         | ties on stable ground vs truth: n, median (GSD), tilt (mm/m) | control's tilt σ (mm/m) | s |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let Some(a) = &r.accuracy else {
            s.push_str(&format!(
                "| {} | {} | – | failed: {} | | | | | | | | | | | | | | {:.1} |\n",
                r.scene,
                r.method,
                r.error.as_deref().unwrap_or("").replace('|', "/"),
                r.seconds
            ));
            continue;
        };
        s.push_str(&format!(
            "| {} | {} | {} | {}/{} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.1} |\n",
            r.scene,
            r.method,
            a.epoch,
            a.images_oriented,
            a.images_given,
            triple(a.check_rmse_m, 3),
            triple(a.check_rmse_gsd, 2),
            triple(a.orientation_check_rmse_m, 3),
            triple(a.disagreement_m, 3),
            triple(a.orientation_disagreement_m, 3),
            triple(a.centre_rmse_m, 3),
            a.rms_px.map_or("–".into(), |v| format!("{v:.3}")),
            a.observations,
            a.inter_epoch_tie_points,
            triple(a.gnss_offset_error_m, 3),
            triple(a.gnss_offset_error_sigmas, 1),
            a.stable_ties.map_or("–".into(), |t| format!(
                "{}, {:+.2}, {:.2}",
                t.count,
                t.median_m / a.gsd_m,
                t.tilt_mm_per_m
            )),
            a.datum_tilt_sigma_mm_per_m
                .map_or("–".into(), |v| format!("{v:.2}")),
            r.seconds
        ));
    }
    s
}

/// (check dH RMS over the epochs in GSD, later epochs' dH disagreement RMS in m).
type Summary = (Option<f64>, Option<f64>);

/// The papers' questions answered from the rows, per scene: how high each strategy's check
/// points are off (RMS of dH over the epochs, in GSD) and how far the later epochs disagree with
/// the reference epoch in height (RMS of the epoch − reference dH over the later epochs, m).
/// The reference is each scene's first epoch, as `synth` writes it.
fn findings(rows: &[Row]) -> String {
    let mut scenes: Vec<&str> = Vec::new();
    let mut methods: Vec<&str> = Vec::new();
    for r in rows {
        if !scenes.contains(&r.scene.as_str()) {
            scenes.push(&r.scene);
        }
        if !methods.contains(&r.method.as_str()) {
            methods.push(&r.method);
        }
    }
    // (check dH RMS in GSD, later epochs' dH disagreement RMS in m) per scene and method.
    let summary = |scene: &str, method: &str| -> Summary {
        let epochs: Vec<&EpochAccuracy> = rows
            .iter()
            .filter(|r| r.scene == scene && r.method == method)
            .filter_map(|r| r.accuracy.as_ref())
            .collect();
        let check: Vec<f64> = epochs
            .iter()
            .filter_map(|a| a.check_rmse_gsd.map(|c| c[2]))
            .collect();
        let apart: Vec<f64> = epochs
            .iter()
            .skip(1)
            .filter_map(|a| a.disagreement_m.map(|d| d[2]))
            .collect();
        (rms(&check), rms(&apart))
    };
    let cell =
        |v: Option<f64>, digits: usize| v.map_or("–".to_string(), |v| format!("{v:.digits$}"));
    let mut s = String::from(
        "\n## Height, per scene: check dH RMS over the epochs (GSD) · epoch − reference dH RMS \
         over the later epochs (m)\n\n| scene |",
    );
    for m in &methods {
        s.push_str(&format!(" {m} |"));
    }
    s.push_str(&format!("\n|---|{}\n", "---|".repeat(methods.len())));
    for scene in &scenes {
        s.push_str(&format!("| {scene} |"));
        for m in &methods {
            let (check, apart) = summary(scene, m);
            s.push_str(&format!(" {} · {} |", cell(check, 2), cell(apart, 3)));
        }
        s.push('\n');
    }
    // The comparisons the papers make, scene by scene.
    let mut compare = |title: &str, a: &str, b: &str, pick: fn(Summary) -> Option<f64>| {
        if !(methods.contains(&a) && methods.contains(&b)) {
            return;
        }
        let (mut yes, mut even, mut no) = (Vec::new(), Vec::new(), Vec::new());
        for scene in &scenes {
            if let (Some(x), Some(y)) = (pick(summary(scene, a)), pick(summary(scene, b))) {
                let entry = format!("{scene} ({x:.2} vs {y:.2})");
                // Within 10 % (or 0.01) is a tie: synthetic noise, not a finding.
                if (x - y).abs() <= (0.1 * x.max(y)).max(0.01) {
                    even.push(entry);
                } else if x > y {
                    yes.push(entry);
                } else {
                    no.push(entry);
                }
            }
        }
        let list = |v: &[String]| {
            if v.is_empty() {
                "–".to_string()
            } else {
                v.join(", ")
            }
        };
        s.push_str(&format!(
            "\n- {title}: on {} of {} scenes: {}; within 10 %: {}; the opposite: {}\n",
            yes.len(),
            yes.len() + even.len() + no.len(),
            list(&yes),
            list(&even),
            list(&no),
        ));
    };
    let (timesift, independent) = (Method::Timesift.name(), Method::Independent.name());
    compare(
        "`chunk` worse than `timesift` in height (check dH, GSD)",
        Method::Chunk.name(),
        timesift,
        |(check, _)| check,
    );
    compare(
        "`timesift` disagrees more than `stp` between epochs in height (m)",
        timesift,
        Method::Stp.name(),
        |(_, apart)| apart,
    );
    compare(
        "`independent` disagrees more than `timesift` between epochs in height (m)",
        independent,
        timesift,
        |(_, apart)| apart,
    );
    s
}

/// The dense, dem and change stages on the current orientation, scored against the truth.
fn products(
    scene: &str,
    method: &str,
    project: &Project,
    reference: Option<(PathBuf, f64)>,
) -> ProductRow {
    let start = Instant::now();
    let mut row = ProductRow {
        scene: scene.to_string(),
        method: method.to_string(),
        pairs: Vec::new(),
        volume_relative_error: None,
        volume_abs_error_m3: None,
        regions_measured: (0, 0),
        against_reference: Vec::new(),
        seconds: 0.0,
        error: None,
    };
    let result = (|| -> anyhow::Result<()> {
        for stage in [Stage::Dense, Stage::Dem, Stage::Change] {
            run_stage(project, stage)?;
        }
        let layout = project.layout();
        for (a, b) in timesift::stages::epoch_pairs(project) {
            let stats: DemReport = read_json(&layout.change_stats(&a, &b))?;
            if let Some(s) = &stats.stable {
                row.pairs.push(PairProduct {
                    pair: format!("{a}__{b}"),
                    stable_mean: s.mean,
                    stable_median: s.median,
                    plane_gain: stats.stable_trend.map(|t| t.gain_m),
                    lod95: stats.lod95,
                });
            }
        }
        if let Some((path, gsd)) = &reference {
            row.against_reference = against_reference(project, path, *gsd)?;
        }
        if layout.truth_dir().join("change.json").is_file() {
            let all = region_volumes(&project_truth(project)?)?;
            let volumes: Vec<_> = all.iter().filter(|v| v.measured_m3.is_finite()).collect();
            row.regions_measured = (volumes.len(), all.len());
            let wrong: f64 = volumes
                .iter()
                .map(|v| (v.measured_m3 - v.true_m3).abs())
                .sum();
            let truth: f64 = volumes.iter().map(|v| v.true_m3.abs()).sum();
            if truth > 0.0 {
                row.volume_abs_error_m3 = Some(wrong);
                row.volume_relative_error = Some(wrong / truth);
            }
        }
        Ok(())
    })();
    row.error = result.err().map(|e| e.to_string());
    row.seconds = start.elapsed().as_secs_f64();
    println!(
        "{scene} {method}: products in {:.0} s{}",
        row.seconds,
        row.error
            .as_ref()
            .map_or(String::new(), |e| format!(" (failed: {e})"))
    );
    row
}

/// Mean over the pairs of |stable-area DoD mean| and of the plane's gain, m.
fn pair_means(r: &ProductRow) -> (Option<f64>, Option<f64>) {
    let n = r.pairs.len() as f64;
    let gains: Vec<f64> = r.pairs.iter().filter_map(|p| p.plane_gain).collect();
    (
        (n > 0.0).then(|| r.pairs.iter().map(|p| p.stable_mean.abs()).sum::<f64>() / n),
        (!gains.is_empty()).then(|| gains.iter().sum::<f64>() / gains.len() as f64),
    )
}

fn product_table(rows: &[ProductRow]) -> String {
    let cell =
        |v: Option<f64>, digits: usize| v.map_or("–".to_string(), |v| format!("{v:.digits$}"));
    let mut s = String::from(
        "\n## Products: stable-area DoD between consecutive epochs and volumes against the truth\n\n\
         | scene | method | mean \\|stable DoD mean\\| m | mean plane gain m | pairs (mean / median / gain / LoD95, m) | volume error | Σ\\|error\\| m³ | regions measured | s |\n\
         |---|---|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        let (mean, gain) = pair_means(r);
        let pairs: Vec<String> = r
            .pairs
            .iter()
            .map(|p| {
                format!(
                    "{}: {:.3} / {:.3} / {} / {}",
                    p.pair,
                    p.stable_mean,
                    p.stable_median,
                    cell(p.plane_gain, 3),
                    cell(p.lod95, 3)
                )
            })
            .collect();
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} of {} | {:.0} |\n",
            r.scene,
            r.method,
            cell(mean, 4),
            cell(gain, 3),
            r.error.clone().unwrap_or_else(|| pairs.join("<br>")),
            r.volume_relative_error
                .map_or("–".into(), |v| format!("{:.0} %", 100.0 * v)),
            cell(r.volume_abs_error_m3, 0),
            r.regions_measured.0,
            r.regions_measured.1,
            r.seconds
        ));
    }
    let against: Vec<String> = rows
        .iter()
        .flat_map(|r| {
            r.against_reference.iter().map(move |a| {
                format!(
                    "| {} | {} | {} | {} | {:.3} | {:.2} | {:.2} |\n",
                    r.scene, r.method, a.epoch, a.cells, a.median_m, a.median_gsd, a.tilt_mm_per_m
                )
            })
        })
        .collect();
    if !against.is_empty() {
        s.push_str(
            "\n## Each epoch's DEM against the reference DEM over the true stable ground (`--ties refdem`)\n\n\
             | scene | method | epoch | cells | median m | median GSD | plane tilt mm/m |\n\
             |---|---|---|---|---|---|---|\n",
        );
        s.push_str(&against.concat());
    }
    // The papers' ordering on the products: the single block and msfm co-register the epochs
    // better than independent blocks on biased GNSS.
    for (better, worse) in [
        (Method::Timesift.name(), Method::Independent.name()),
        (Method::Msfm.name(), Method::Independent.name()),
    ] {
        let mut verdicts = Vec::new();
        for scene in rows
            .iter()
            .map(|r| r.scene.as_str())
            .collect::<std::collections::BTreeSet<_>>()
        {
            let find = |m: &str| rows.iter().find(|r| r.scene == scene && r.method == m);
            if let (Some(a), Some(b)) = (find(better), find(worse)) {
                let ((ma, ga), (mb, gb)) = (pair_means(a), pair_means(b));
                verdicts.push(format!(
                    "{scene}: |mean| {} vs {} m, gain {} vs {} m, volume error {} vs {}",
                    cell(ma, 4),
                    cell(mb, 4),
                    cell(ga, 3),
                    cell(gb, 3),
                    a.volume_relative_error
                        .map_or("–".into(), |v| format!("{:.0} %", 100.0 * v)),
                    b.volume_relative_error
                        .map_or("–".into(), |v| format!("{:.0} %", 100.0 * v)),
                ));
            }
        }
        if !verdicts.is_empty() {
            s.push_str(&format!(
                "\n- `{better}` against `{worse}` on the products: {}\n",
                verdicts.join("; ")
            ));
        }
    }
    s
}
