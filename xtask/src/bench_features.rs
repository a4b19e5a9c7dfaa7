//! `cargo xtask bench features`: timesift's SIFT and LDB against OpenCV SIFT and COLMAP's CPU
//! SIFT, on the same inputs, in one run.
//!
//! - Quality on real multi-date data: the sandpyper `mar` orthophotos (9 dates of one beach on
//!   nearly the same 1 m grid). The true correspondence between two dates is given by their
//!   geotransforms, so a match is correct when the keypoint of date b lies within 2 px of where
//!   the geotransforms put the keypoint of date a. Every pair of dates is matched the same way
//!   for every method (nearest neighbour, Lowe ratio 0.8, no mutual check) with the same keypoint
//!   budget; OpenCV's keypoints and descriptors come from `xtask/scripts/opencv_sift.py`. All
//!   methods read the same grey images and nodata masks, written by this benchmark.
//! - Speed: seconds per image on the 29 `lund` photos (1024 × 768) and on a 12 MP image (a lund
//!   photo upsampled to 4000 × 3000), with 1 and 2 threads, decoding included, against OpenCV
//!   SIFT and `colmap feature_extractor` (CPU, `max_image_size` raised so it does not downscale).
//!
//! A missing peer is reported and its columns are left empty.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, bail};
use timesift_features::files::extract_files;
use timesift_features::text::{DescriptorKind, read};
use timesift_features::{
    DetectorOptions, FeatureExtractor, Features, GreyImage, KeypointLimit, LdbExtractor, Mask,
    SiftExtractor, SiftNormalization,
};
use timesift_io::geotiff::{GeoTransform, read_bands_f32};
use timesift_matching::{FloatDistance, MatchOptions, match_descriptors};

const OPENCV_SCRIPT: &str = include_str!("../scripts/opencv_sift.py");

const DATES: [&str; 9] = [
    "20180601", "20180621", "20180727", "20180925", "20181113", "20181211", "20190205", "20190313",
    "20190516",
];
/// Lowe's ratio for the quality comparison (fixed by the issue).
const RATIO: f32 = 0.8;
/// A match is correct within this many pixels of the geotransform's prediction.
const CORRECT_PX: f64 = 2.0;
/// Keypoint budget of the speed runs (COLMAP's default `max_num_features`).
const SPEED_BUDGET: usize = 8192;

/// One date's orthophoto as the methods see it.
struct Date {
    name: String,
    width: usize,
    height: usize,
    grey: Vec<f32>,
    mask: Vec<u8>,
    transform: GeoTransform,
    grey_png: PathBuf,
    mask_png: PathBuf,
}

/// Options of the run.
pub struct FeaturesBench {
    pub budget: usize,
    pub quality: bool,
    pub speed: bool,
    /// Also time a 100 MP image and report the process's peak memory.
    pub large: bool,
}

pub fn run(options: &FeaturesBench) -> anyhow::Result<()> {
    let dir = std::env::temp_dir().join(format!("timesift-bench-features-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let script = dir.join("opencv_sift.py");
    std::fs::write(&script, OPENCV_SCRIPT)?;
    if options.quality {
        quality(&dir, &script, options.budget)?;
    }
    if options.speed {
        speed(&dir, &script)?;
    }
    if options.large {
        large(&dir)?;
    }
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}

fn detector(budget: usize) -> DetectorOptions {
    DetectorOptions {
        limit: Some(KeypointLimit::spread(budget)),
        ..DetectorOptions::default()
    }
}

fn load_dates(dir: &Path) -> anyhow::Result<Vec<Date>> {
    DATES
        .iter()
        .map(|date| {
            let path = crate::shared_data()
                .join("sandpyper-mar/ortho")
                .join(format!("mar_{date}_ortho_resampled_1m.tif"));
            let raster = read_bands_f32(&path).with_context(|| path.display().to_string())?;
            let (w, h, b) = (raster.width, raster.height, raster.bands);
            let mut grey_u8 = Vec::with_capacity(w * h);
            let mut mask = Vec::with_capacity(w * h);
            for px in raster.data.chunks(b) {
                let value = if b >= 3 {
                    0.299 * px[0] + 0.587 * px[1] + 0.114 * px[2]
                } else {
                    px[0]
                };
                grey_u8.push(value.round().clamp(0.0, 255.0) as u8);
                mask.push(if px.iter().take(3).any(|&v| v != 0.0) {
                    255
                } else {
                    0
                });
            }
            let grey_png = dir.join(format!("mar_{date}.png"));
            let mask_png = dir.join(format!("mar_{date}_mask.png"));
            image::GrayImage::from_raw(w as u32, h as u32, grey_u8.clone())
                .context("grey buffer")?
                .save(&grey_png)?;
            image::GrayImage::from_raw(w as u32, h as u32, mask.clone())
                .context("mask buffer")?
                .save(&mask_png)?;
            Ok(Date {
                name: date.to_string(),
                width: w,
                height: h,
                grey: grey_u8.iter().map(|&v| v as f32 / 255.0).collect(),
                mask,
                transform: raster.georef.transform,
                grey_png,
                mask_png,
            })
        })
        .collect()
}

/// Ratio-test matches a → b (nearest neighbour, no mutual check) and how many of them the
/// geotransforms confirm.
fn correct_matches(
    a: &Features,
    ta: &GeoTransform,
    b: &Features,
    tb: &GeoTransform,
) -> anyhow::Result<(usize, usize)> {
    let matches = match_descriptors(
        &a.descriptors,
        &b.descriptors,
        &MatchOptions {
            ratio: RATIO,
            mutual: false,
            max_distance: None,
            ratio_on: FloatDistance::Euclidean,
        },
    )?;
    let correct = matches
        .iter()
        .filter(|m| {
            let ka = &a.keypoints[m.query as usize];
            let kb = &b.keypoints[m.train as usize];
            let (x, y) = ta.pixel_to_world(ka.x, ka.y);
            let (u, v) = tb.world_to_pixel(x, y);
            (kb.x - u).hypot(kb.y - v) <= CORRECT_PX
        })
        .count();
    Ok((matches.len(), correct))
}

fn quality(dir: &Path, script: &Path, budget: usize) -> anyhow::Result<()> {
    let dates = load_dates(dir)?;
    println!(
        "Quality: sandpyper `mar` orthophotos, {} dates, every pair; budget {budget} keypoints \
         (timesift: half spread over 8 x 8 cells, OpenCV: strongest), ratio {RATIO}, correct \
         within {CORRECT_PX} px of the geotransforms",
        dates.len()
    );
    let mut methods: Vec<(&str, Vec<Features>)> = Vec::new();
    let mut args: Vec<String> = vec![
        "quality".into(),
        "--budget".into(),
        budget.to_string(),
        "--out".into(),
        dir.display().to_string(),
    ];
    args.extend(
        dates
            .iter()
            .map(|d| format!("{}:{}", d.grey_png.display(), d.mask_png.display())),
    );
    match crate::python_json(script, &args) {
        Ok(report) => {
            let features: anyhow::Result<Vec<Features>> = dates
                .iter()
                .map(|d| {
                    Ok(read(
                        &dir.join(format!("mar_{}.txt", d.name)),
                        DescriptorKind::Float,
                    )?)
                })
                .collect();
            methods.push(("opencv", features?));
            println!("  OpenCV {}", report["version"].as_str().unwrap_or("?"));
        }
        Err(e) => println!("  OpenCV SIFT unavailable ({e}); its column is empty"),
    }
    let extractors: [(&str, Box<dyn FeatureExtractor>); 3] = [
        (
            "sift",
            Box::new(SiftExtractor {
                detector: detector(budget),
                normalization: SiftNormalization::L2,
            }),
        ),
        (
            "rootsift",
            Box::new(SiftExtractor {
                detector: detector(budget),
                normalization: SiftNormalization::Root,
            }),
        ),
        (
            "ldb",
            Box::new(LdbExtractor {
                detector: detector(budget),
            }),
        ),
    ];
    for (name, extractor) in &extractors {
        let features: anyhow::Result<Vec<Features>> = dates
            .iter()
            .map(|d| {
                let image = GreyImage::new(d.width, d.height, &d.grey)?;
                let mask = Mask::new(d.width, d.height, &d.mask)?;
                Ok(extractor.extract(&image, Some(&mask))?)
            })
            .collect();
        methods.push((name, features?));
    }
    print!("  {:<19}", "keypoints per date");
    for (name, features) in &methods {
        let mean = features.iter().map(|f| f.keypoints.len()).sum::<usize>() as f64
            / features.len() as f64;
        print!(" {name:>9}: {mean:6.0}");
    }
    println!();
    print!("  {:<19}", "pair (a -> b)");
    for (name, _) in &methods {
        print!(" {:>17}", format!("{name} ok/matched"));
    }
    println!();
    let mut totals = vec![(0usize, 0usize); methods.len()];
    for i in 0..dates.len() {
        for j in i + 1..dates.len() {
            print!("  {:<19}", format!("{} {}", dates[i].name, dates[j].name));
            for (m, (_, features)) in methods.iter().enumerate() {
                let (matched, correct) = correct_matches(
                    &features[i],
                    &dates[i].transform,
                    &features[j],
                    &dates[j].transform,
                )?;
                totals[m].0 += matched;
                totals[m].1 += correct;
                print!(" {:>17}", format!("{correct}/{matched}"));
            }
            println!();
        }
    }
    print!("  {:<19}", "total");
    for (correct_total, matched_total) in totals.iter().map(|t| (t.1, t.0)) {
        print!(" {:>17}", format!("{correct_total}/{matched_total}"));
    }
    println!();
    let total = |name: &str| {
        methods
            .iter()
            .position(|(n, _)| *n == name)
            .map(|m| totals[m].1 as f64)
    };
    if let (Some(ours), Some(theirs)) = (total("sift"), total("opencv")) {
        println!(
            "  correct matches, timesift SIFT / OpenCV SIFT: {:.3}",
            ours / theirs
        );
    }
    if let (Some(ours), Some(theirs)) = (total("rootsift"), total("opencv")) {
        println!(
            "  correct matches, timesift RootSIFT / OpenCV SIFT: {:.3}",
            ours / theirs
        );
    }
    if let (Some(ldb), Some(sift)) = (total("ldb"), total("sift")) {
        println!(
            "  correct matches, timesift LDB / timesift SIFT: {:.3}",
            ldb / sift
        );
    }
    Ok(())
}

/// Seconds per image of timesift on `paths` with `threads` threads, and mean keypoints.
fn timesift_speed(
    paths: &[PathBuf],
    extractor: &dyn FeatureExtractor,
    threads: usize,
) -> anyhow::Result<(f64, f64)> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?;
    // Warm-up on the first image (page cache, allocator).
    pool.install(|| extract_files(&paths[..1], extractor, |_, _, _| {}));
    let keypoints = std::sync::atomic::AtomicUsize::new(0);
    let failures = std::sync::Mutex::new(Vec::new());
    let start = Instant::now();
    pool.install(|| {
        extract_files(paths, extractor, |_, path, result| match result {
            Ok(f) => {
                keypoints.fetch_add(f.keypoints.len(), std::sync::atomic::Ordering::Relaxed);
            }
            Err(e) => failures
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .push(format!("{}: {e}", path.display())),
        })
    });
    let seconds = start.elapsed().as_secs_f64();
    if let Some(first) = failures.into_inner().unwrap_or_default().first() {
        bail!("{first}");
    }
    Ok((
        seconds / paths.len() as f64,
        keypoints.into_inner() as f64 / paths.len() as f64,
    ))
}

/// Seconds per image of `colmap feature_extractor` (CPU) on the images of `image_dir`.
fn colmap_speed(dir: &Path, image_dir: &Path, count: usize, threads: usize) -> anyhow::Result<f64> {
    let database = dir.join(format!("colmap-{threads}.db"));
    let _ = std::fs::remove_file(&database);
    let seconds = crate::colmap(&[
        "feature_extractor".into(),
        "--database_path".into(),
        database.display().to_string(),
        "--image_path".into(),
        image_dir.display().to_string(),
        "--ImageReader.single_camera".into(),
        "1".into(),
        "--SiftExtraction.use_gpu".into(),
        "0".into(),
        "--SiftExtraction.num_threads".into(),
        threads.to_string(),
        "--SiftExtraction.max_image_size".into(),
        "6000".into(),
        "--SiftExtraction.max_num_features".into(),
        SPEED_BUDGET.to_string(),
    ]);
    let _ = std::fs::remove_file(&database);
    let seconds = seconds?;
    Ok(seconds / count as f64)
}

fn speed(dir: &Path, script: &Path) -> anyhow::Result<()> {
    let lund_dir = crate::shared_data().join("opensfm/lund/images");
    let lund = crate::lund_images()?;
    // The 12 MP image: a lund photo upsampled to 4000 × 3000, three copies so that process start
    // is amortised for COLMAP.
    let big_dir = dir.join("12mp");
    std::fs::create_dir_all(&big_dir)?;
    let photo = image::open(&lund[0])?;
    let big = photo.resize_exact(4000, 3000, image::imageops::FilterType::CatmullRom);
    let mut big_paths = Vec::new();
    for name in ["a", "b", "c"] {
        let path = big_dir.join(format!("12mp_{name}.jpg"));
        let file = std::fs::File::create(&path)?;
        let mut encoder =
            image::codecs::jpeg::JpegEncoder::new_with_quality(std::io::BufWriter::new(file), 95);
        encoder.encode_image(&big.to_rgb8())?;
        big_paths.push(path);
    }
    let sift = SiftExtractor {
        detector: detector(SPEED_BUDGET),
        normalization: SiftNormalization::L2,
    };
    let ldb = LdbExtractor {
        detector: detector(SPEED_BUDGET),
    };
    println!(
        "\nSpeed: seconds per image (decoding included), budget {SPEED_BUDGET} keypoints; \
         ratio = peer / timesift SIFT (> 1: timesift faster)"
    );
    println!(
        "  {:<22} {:>7} {:>14} {:>14} {:>16} {:>16} {:>10} {:>10}",
        "images",
        "threads",
        "timesift SIFT",
        "timesift LDB",
        "OpenCV (ratio)",
        "COLMAP (ratio)",
        "kp ours",
        "kp OpenCV"
    );
    for (label, paths, image_dir) in [
        ("lund 1024x768 (29)", &lund, lund_dir.as_path()),
        ("12 MP 4000x3000 (3)", &big_paths, big_dir.as_path()),
    ] {
        for threads in [1, 2] {
            let (ours, kp_ours) = timesift_speed(paths, &sift, threads)?;
            let (ours_ldb, _) = timesift_speed(paths, &ldb, threads)?;
            let mut args: Vec<String> = vec![
                "speed".into(),
                "--budget".into(),
                SPEED_BUDGET.to_string(),
                "--threads".into(),
                threads.to_string(),
            ];
            args.extend(paths.iter().map(|p| p.display().to_string()));
            let opencv = crate::python_json(script, &args);
            let colmap = colmap_speed(dir, image_dir, paths.len(), threads);
            let (opencv_text, kp_opencv) = match &opencv {
                Ok(r) => {
                    let s = r["seconds_per_image"].as_f64().unwrap_or(f64::NAN);
                    (
                        format!("{s:.3} ({:.2})", s / ours),
                        format!("{:.0}", r["keypoints"].as_f64().unwrap_or(f64::NAN)),
                    )
                }
                Err(e) => (format!("n/a: {e}"), "-".into()),
            };
            let colmap_text = match &colmap {
                Ok(s) => format!("{s:.3} ({:.2})", s / ours),
                Err(e) => format!("n/a: {e}"),
            };
            println!(
                "  {label:<22} {threads:>7} {ours:>14.3} {ours_ldb:>14.3} {opencv_text:>16} {colmap_text:>16} {kp_ours:>10.0} {kp_opencv:>10}"
            );
        }
    }
    Ok(())
}

/// Peak resident memory of this process so far, MiB (Linux `VmHWM`).
fn peak_rss_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

/// Extracts SIFT from one image in this (fresh) process and prints seconds, keypoints and peak
/// memory as JSON: the child side of the 100 MP run.
pub fn measure_one(path: &Path, budget: usize, memory_mib: usize) -> anyhow::Result<()> {
    let before = peak_rss_mib();
    let start = Instant::now();
    let image = timesift_io::image::read_grey(path)?;
    let decoded = start.elapsed().as_secs_f64();
    let grey = GreyImage::from_io(&image)?;
    let features = SiftExtractor {
        detector: DetectorOptions {
            memory_budget: memory_mib << 20,
            ..detector(budget)
        },
        normalization: SiftNormalization::L2,
    }
    .extract(&grey, None)?;
    println!(
        "{}",
        serde_json::json!({
            "width": image.width, "height": image.height,
            "seconds": start.elapsed().as_secs_f64(), "decode_seconds": decoded,
            "keypoints": features.keypoints.len(),
            "peak_rss_mib": peak_rss_mib(), "rss_before_mib": before,
            "grey_image_mib": (image.data.len() * 4) as f64 / (1024.0 * 1024.0),
        })
    );
    Ok(())
}

/// A 100 MP image (a lund photo upsampled to 11548 × 8660), extracted in a fresh process per
/// thread count and scale-space budget: time and peak memory.
fn large(dir: &Path) -> anyhow::Result<()> {
    let lund = crate::shared_data().join("opensfm/lund/images/01.jpg");
    println!();
    let path = dir.join("100mp.png");
    let big = image::open(&lund)?.resize_exact(11548, 8660, image::imageops::FilterType::Triangle);
    big.to_luma8().save(&path)?;
    drop(big);
    for (threads, memory_mib) in [(1, 512), (2, 512), (2, 256), (2, 1024)] {
        let output = Command::new(std::env::current_exe()?)
            .args(["bench", "features", "--measure-one"])
            .arg(&path)
            .args(["--memory-mib", &memory_mib.to_string()])
            .env("RAYON_NUM_THREADS", threads.to_string())
            .output()?;
        if !output.status.success() {
            bail!("{}", String::from_utf8_lossy(&output.stderr));
        }
        let report: serde_json::Value = serde_json::from_slice(&output.stdout)?;
        println!(
            "100 MP ({} x {}), {threads} thread(s), scale-space budget {memory_mib} MiB: {:.1} s \
             ({:.1} s decoding), {} keypoints, peak memory {:.0} MiB (the decoded grey image alone: \
             {:.0} MiB)",
            report["width"],
            report["height"],
            report["seconds"].as_f64().unwrap_or(f64::NAN),
            report["decode_seconds"].as_f64().unwrap_or(f64::NAN),
            report["keypoints"],
            report["peak_rss_mib"].as_f64().unwrap_or(f64::NAN),
            report["grey_image_mib"].as_f64().unwrap_or(f64::NAN),
        );
    }
    Ok(())
}
