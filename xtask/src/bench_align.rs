//! `cargo xtask bench align`: images to oriented block on the 29 `lund` photos, timesift against
//! COLMAP's CPU pipeline (`feature_extractor`, `exhaustive_matcher`, `mapper`), both with 2
//! threads, in one run: images oriented, RMS reprojection error (computed the same way for both:
//! every observation of every 3-D point reprojected through the model's camera, docs/design.md pixel
//! convention, which COLMAP shares), points, wall time and the time ratio.
//!
//! timesift runs as a user would: a project whose one epoch is the `lund` folder (linked, not
//! copied), EXIF GPS priors in UTM 33N, `timesift run --to align` with its defaults (epoch-aware
//! pairs by GPS position, RootSIFT, self-calibration, georeferencing).

use std::path::Path;
use std::time::Instant;

use anyhow::Context;
use timesift_core::project_world;
use timesift_io::colmap::{ColmapModel, camera_from_colmap, read_colmap_text};

const THREADS: usize = 2;

/// RMS reprojection error over all observations of a COLMAP text model, pixels, and the number
/// of observations.
fn model_rms(model: &ColmapModel) -> anyhow::Result<(f64, usize)> {
    let cameras = model
        .cameras
        .iter()
        .map(|(id, c)| {
            camera_from_colmap(&c.model, c.width, c.height, &c.params)
                .map(|camera| (*id, camera))
                .map_err(|e| anyhow::anyhow!("camera {id}: {e}"))
        })
        .collect::<anyhow::Result<std::collections::BTreeMap<_, _>>>()?;
    let mut sum = 0.0;
    let mut n = 0;
    for point in model.points.values() {
        for &(image_id, index) in &point.track {
            let image = model
                .images
                .get(&image_id)
                .with_context(|| format!("point refers to missing image {image_id}"))?;
            let camera = cameras
                .get(&image.camera_id)
                .with_context(|| format!("image refers to missing camera {}", image.camera_id))?;
            let (x, y, _) = image.points2d[index as usize];
            let u = project_world(camera, &image.pose, &point.xyz)
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            sum += (u - nalgebra::Vector2::new(x, y)).norm_squared();
            n += 1;
        }
    }
    Ok(((sum / n.max(1) as f64).sqrt(), n))
}

pub fn run() -> anyhow::Result<()> {
    let images = crate::shared_data().join("opensfm/lund/images");
    let work = std::env::temp_dir().join(format!("timesift-bench-align-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&work);
    std::fs::create_dir_all(work.join("project/images"))?;
    let n = crate::lund_images()?.len();
    // timesift, in process on a pool of 2 threads.
    let dir = work.join("project");
    std::os::unix::fs::symlink(&images, dir.join("images/lund"))?;
    std::fs::write(
        dir.join("project.toml"),
        "crs = \"EPSG:32633\"\n[[epoch]]\nname = \"lund\"\nimages = \"images/lund/*.jpg\"\n",
    )?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(THREADS)
        .build()?;
    let start = Instant::now();
    pool.install(|| -> anyhow::Result<()> {
        let project = timesift::Project::load(&dir)?;
        timesift::stages::run(&project, None, Some(timesift::stages::Stage::Align))?;
        Ok(())
    })?;
    let ours_seconds = start.elapsed().as_secs_f64();
    let layout = timesift::layout::Layout::new(&dir);
    let ours = read_colmap_text(&layout.colmap_dir())?;
    let (ours_rms, ours_obs) = model_rms(&ours)?;
    let report: timesift::report::AlignReport = timesift::report::read_json(&layout.report_json())?;
    println!("lund, {n} images, {THREADS} threads, images to oriented block");
    println!(
        "  {:<10} {:>9} {:>9} {:>13} {:>9} {:>9}",
        "", "oriented", "points", "observations", "RMS px", "seconds"
    );
    println!(
        "  {:<10} {:>9} {:>9} {:>13} {:>9.3} {:>9.1}   (datum {}, GNSS priors rejected {})",
        "timesift",
        ours.images.len(),
        ours.points.len(),
        ours_obs,
        ours_rms,
        ours_seconds,
        report.datum,
        report.gnss_priors_rejected
    );
    match colmap(&images, &work) {
        Ok((model, seconds)) => {
            let (rms, obs) = model_rms(&model)?;
            println!(
                "  {:<10} {:>9} {:>9} {:>13} {:>9.3} {:>9.1}",
                "COLMAP",
                model.images.len(),
                model.points.len(),
                obs,
                rms,
                seconds
            );
            println!(
                "  time ratio COLMAP / timesift: {:.2}; RMS ratio timesift / COLMAP: {:.3}",
                seconds / ours_seconds,
                ours_rms / rms
            );
        }
        Err(e) => {
            // Kept for diagnosis: the database, the mapper's log and whatever it wrote.
            println!(
                "  COLMAP unavailable: {e} (work kept in {})",
                work.display()
            );
            return Ok(());
        }
    }
    let _ = std::fs::remove_dir_all(&work);
    Ok(())
}

/// COLMAP's CPU pipeline on the images; its largest model (as text) and the summed wall time.
fn colmap(images: &Path, work: &Path) -> anyhow::Result<(ColmapModel, f64)> {
    let database = work.join("colmap.db").display().to_string();
    let sparse = work.join("sparse");
    std::fs::create_dir_all(&sparse)?;
    let threads = THREADS.to_string();
    let s = |v: &str| v.to_string();
    let mut seconds = crate::colmap(&[
        s("feature_extractor"),
        s("--database_path"),
        database.clone(),
        s("--image_path"),
        images.display().to_string(),
        s("--ImageReader.single_camera"),
        s("1"),
        s("--SiftExtraction.use_gpu"),
        s("0"),
        s("--SiftExtraction.num_threads"),
        threads.clone(),
    ])?;
    seconds += crate::colmap(&[
        s("exhaustive_matcher"),
        s("--database_path"),
        database.clone(),
        s("--SiftMatching.use_gpu"),
        s("0"),
        s("--SiftMatching.num_threads"),
        threads.clone(),
    ])?;
    let mapper = |extra: &[String]| -> anyhow::Result<f64> {
        let mut args = vec![
            s("mapper"),
            s("--database_path"),
            database.clone(),
            s("--image_path"),
            images.display().to_string(),
            s("--output_path"),
            sparse.display().to_string(),
            s("--Mapper.num_threads"),
            threads.clone(),
        ];
        args.extend_from_slice(extra);
        let started = Instant::now();
        let output = std::process::Command::new("colmap")
            .args(&args)
            .output()
            .context("running colmap mapper")?;
        let mut log = output.stdout.clone();
        log.extend_from_slice(&output.stderr);
        std::fs::write(work.join("mapper.log"), &log)?;
        if !output.status.success() {
            anyhow::bail!("colmap mapper exit status {}", output.status);
        }
        Ok(started.elapsed().as_secs_f64())
    };
    // COLMAP 3.8's mapper exits with "failed to create sparse model" when its last attempt to
    // start another model fails, even after writing a model: what it wrote counts.
    // Its initial-pair search is randomised and this walking sequence has small baselines: when
    // the defaults start no model, it runs again with relaxed thresholds, first a 4° initial
    // triangulation angle (timesift relaxes its own thresholds the same way), then 2° with a
    // laxer absolute pose; only the run that made the model is timed.
    let has_model = || std::fs::read_dir(&sparse).is_ok_and(|mut d| d.next().is_some());
    let relaxations: [&[&str]; 3] = [
        &[],
        &["--Mapper.init_min_tri_angle", "4"],
        &[
            "--Mapper.init_min_tri_angle",
            "2",
            "--Mapper.abs_pose_min_num_inliers",
            "15",
            "--Mapper.abs_pose_min_inlier_ratio",
            "0.15",
        ],
    ];
    for (k, extra) in relaxations.iter().enumerate() {
        if k > 0 {
            println!(
                "  (COLMAP mapper made no model; again with {})",
                extra.join(" ")
            );
        }
        let started = Instant::now();
        let extra: Vec<String> = extra.iter().map(|v| s(v)).collect();
        if let Err(e) = mapper(&extra) {
            println!("  (COLMAP mapper exit status: {e})");
        }
        if has_model() {
            seconds += started.elapsed().as_secs_f64();
            break;
        }
    }
    // The largest model (COLMAP numbers them 0, 1, … by creation).
    let mut best: Option<ColmapModel> = None;
    for entry in std::fs::read_dir(&sparse)?.flatten() {
        let text = work.join(format!("text-{}", entry.file_name().to_string_lossy()));
        std::fs::create_dir_all(&text)?;
        crate::colmap(&[
            s("model_converter"),
            s("--input_path"),
            entry.path().display().to_string(),
            s("--output_path"),
            text.display().to_string(),
            s("--output_type"),
            s("TXT"),
        ])?;
        let model = read_colmap_text(&text)?;
        if best
            .as_ref()
            .is_none_or(|b| model.images.len() > b.images.len())
        {
            best = Some(model);
        }
    }
    let model = best.context("COLMAP's mapper produced no model")?;
    Ok((model, seconds))
}
