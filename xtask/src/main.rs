//! `cargo xtask`: developer tasks that are not part of the product.
//!
//! - `data`: checks that the shared real data the tests and benches read in place
//!   (`../shared/data`) is present.
//! - `bench geometry`: timesift's RANSAC against OpenCV's on the same correspondences.
//! - `bench bundle`: the BAL problems through timesift's bundle adjuster.
//! - `bench features`: SIFT and LDB against OpenCV SIFT and COLMAP's CPU SIFT (quality on the
//!   sandpyper `mar` orthophotos, seconds per image on `lund`).
//! - `bench matching`: exhaustive matching of `lund` against COLMAP's CPU exhaustive matcher.
//! - `bench align`: images to oriented block on `lund` against COLMAP's CPU pipeline (time, RMS
//!   reprojection error).
//! - `bench change`: Nuth & Kääb / DoD statistics against xdem and M3C2 against py4dgeo.
//! - `bench memory`: peak resident memory of features on 100 MP, dense and a large ortho of
//!   `rendered-mar`, `timesift dem` of 30 million points, against their budgets.
//! - `bench scale [--max-images N]`: every stage's time, memory and files on `synth scale-N`
//!   blocks of 100 to 1,600 images, growth exponents, accuracy per N, a log-log plot.
//!
//! - `fn-lengths [--max-lines N] [--check COUNT]`: the functions over N lines in the shipped
//!   code, and whether each says why it stays long.
//!
//! - `slurm-up` / `slurm-down`: a one-node Slurm cluster on this machine for the cluster tests.
//!
//! - `api [--bless]`: the public API of every library crate against its snapshot in `api/`.
//!
//! - `synth <scene> --out DIR [--seed N] [--scale small|full]`: a synthetic multi-epoch project
//!   with its ground truth (`timesift-synth`).
//!
//! - `bench-methods [--scenes a,b] [--methods m,n] [--scale small|full] [--out DIR]
//!   [--no-products]`: every synthetic scene × every co-registration strategy, compared with the
//!   truth: orientation, and (unless `--no-products`) the stable-area DoDs between epochs and
//!   the volume change of the true regions (tables as markdown and JSON).

mod api;
mod bench_align;
mod bench_bundle;
mod bench_change;
mod bench_coreg;
mod bench_dense;
mod bench_dense_lund;
mod bench_dense_mar;
mod bench_dense_openmvs;
mod bench_dense_peer;
mod bench_dense_time;
mod bench_features;
mod bench_film;
mod bench_geometry;
mod bench_matching;
mod bench_memory;
mod bench_methods;
mod bench_raster;
mod bench_scale;
mod bench_scale_colmap;
mod fn_lengths;
mod fuzz;
mod slurm;

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "xtask")]
struct Cli {
    #[command(subcommand)]
    task: Task,
}

#[derive(Subcommand)]
enum Task {
    /// Check that ../shared/data holds the data sets the tests and benches read.
    Data,
    /// Write a synthetic multi-epoch scene: a project directory plus truth/.
    Synth {
        /// Scene: archival, glacier, orchard, soil-pit, shore, campus or landslide.
        scene: String,
        /// Output directory (created).
        #[arg(long)]
        out: PathBuf,
        /// Seed of every random choice.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// small (tests: ≤ ~60 images of ≤ 0.5 MP) or full (hundreds of images of several MP).
        #[arg(long, default_value = "small")]
        scale: String,
        /// Write the geometry and truth only, not the images.
        #[arg(long)]
        no_images: bool,
        /// Every epoch as film scans (fiducial marks, data strip, a scan transform per image),
        /// as `archival` is.
        #[arg(long)]
        film: bool,
    },
    /// Every synthetic scene × every co-registration strategy against the truth.
    BenchMethods {
        /// Scenes, comma-separated (default: all seven).
        #[arg(long, value_delimiter = ',')]
        scenes: Option<Vec<String>>,
        /// Strategies, comma-separated (default: all six, in the papers' order).
        #[arg(long, value_delimiter = ',')]
        methods: Option<Vec<String>>,
        /// small or full.
        #[arg(long, default_value = "small")]
        scale: String,
        /// Seeds of the scenes, comma-separated: every scene is rendered and run once per
        /// seed, and the reference-epoch table pools the seeds.
        #[arg(long, value_delimiter = ',', default_value = "1")]
        seed: Vec<u64>,
        /// Output folder (scenes, outputs per strategy, methods.md, methods.json).
        #[arg(long, default_value = "target/bench-methods")]
        out: PathBuf,
        /// Orientation only: skip the dense, dem and change stages per strategy (and so the
        /// stable-area DoDs and volumes).
        #[arg(long)]
        no_products: bool,
        /// Products with the default `[dense]` settings rather than the demo's lighter ones.
        #[arg(long)]
        full_dense: bool,
        /// Inter-epoch ties of the single-block strategies, one run each: default, all, plain
        /// (all ties and no GNSS offsets: the plain single block), before (plain with a pooled
        /// outlier bound: the single block as issue 22 found it), pooled (one outlier bound
        /// for the whole block, not one per camera group), auto-blind (change detected from the
        /// ties, stable areas hidden from align), joined (a second look for inter-epoch ties by
        /// descriptor after the first block), nosurface (no surface ties: the later epochs' tie
        /// points not held to the reference epoch's surface), auto-blind-nosurface (auto-blind without
        /// them), refgnss (only the reference epoch's GNSS priors),
        /// scatter-all (every flight's GNSS priors weighed by their scatter), cal:k1+b1+b2 (the
        /// intrinsics the final adjustments estimate, `[align] self_calibration`; cal:none: none),
        /// refdem (no control point, camera centres from a 20 m photo index, and the last
        /// epoch's true surface with 0.3 GSD of noise and 0.5 m added as `[align]
        /// reference_dem`; each epoch's DEM is then scored against it over stable ground).
        #[arg(long, value_delimiter = ',', default_value = "default")]
        ties: Vec<String>,
    },
    /// Functions longer than a bound in the shipped code (not tests, examples or xtask), with
    /// the reason each one written above it gives for staying long.
    FnLengths {
        /// The bound, lines from `fn` to the closing brace.
        #[arg(long, default_value_t = 100)]
        max_lines: usize,
        /// Fail when more functions than this are over the bound, or any has no reason.
        #[arg(long)]
        check: Option<usize>,
        /// Another checkout to measure (default: this workspace).
        #[arg(long)]
        root: Option<PathBuf>,
    },
    /// Start a one-node Slurm cluster on this machine (installs slurm-wlm and munge if
    /// missing; configuration and state under /tmp/timesift-slurm).
    SlurmUp,
    /// Stop the cluster of `slurm-up` and remove its state.
    SlurmDown,
    /// Every reader fuzzed: libFuzzer on nightly (cargo-fuzz), else the stable fallback
    /// (seeded mutation of the corpus); a table of executions, corpus and findings per target.
    Fuzz {
        /// Minutes per target.
        #[arg(long, default_value_t = 1.0)]
        minutes: f64,
        /// Only these targets (comma-separated; default all).
        #[arg(long, value_delimiter = ',')]
        targets: Vec<String>,
        /// Write the seed corpus (timesift's writers and ../shared/data) first.
        #[arg(long)]
        seed: bool,
        /// The stable fallback even where libFuzzer is available.
        #[arg(long)]
        stable: bool,
        /// Targets fuzzed at once.
        #[arg(long, default_value_t = 2)]
        jobs: usize,
    },
    /// One target's stable fuzz campaign in this process (what `fuzz` runs in a child).
    #[command(hide = true)]
    FuzzWorker {
        target: String,
        #[arg(long)]
        seconds: f64,
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// The guide's generated reference pages (project.toml keys, every command's --help)
    /// checked against the code, then the book built with mdbook when it is installed.
    Guide {
        /// Rewrite the reference pages instead of comparing.
        #[arg(long)]
        bless: bool,
    },
    /// The public API of every library crate against its snapshot under `api/`.
    Api {
        /// Rewrite the snapshots instead of comparing.
        #[arg(long)]
        bless: bool,
    },
    /// Stage benchmarks against peers, printing time ratios.
    Bench {
        #[command(subcommand)]
        stage: BenchStage,
    },
    /// The dense stage of a project, alone in this process (the dense bench times it so).
    #[command(hide = true)]
    RunDense {
        /// Project directory.
        dir: PathBuf,
    },
    /// One stage of a project, alone in this process (the scale bench times each so).
    #[command(hide = true)]
    RunStage {
        /// Project directory.
        dir: PathBuf,
        /// The stage.
        #[arg(value_enum)]
        stage: timesift::stages::Stage,
    },
    /// COLMAP 4's mappers on an oriented scale-bench block's matches, scored beside its own
    /// orientation (the scale bench's peer rows, for one block by hand).
    #[command(hide = true)]
    ScalePeers {
        /// Project directory (a `synth scale-N` block after its align stage).
        dir: PathBuf,
        /// A Python with pycolmap 4.
        #[arg(long, env = "PYCOLMAP_PYTHON")]
        python: PathBuf,
    },
    /// Check points of an oriented `synth scale-N` block against its truth, per epoch in GSD
    /// (the scale bench's accuracy columns, for an align stage run by hand).
    #[command(hide = true)]
    ScoreAlign {
        /// Project directory (a `synth scale-N` block after its align stage).
        dir: PathBuf,
    },
    /// The DEM scores of a rendered-mar project's dense clouds as they are (the dense bench's
    /// scoring, for trying `[dense]` settings by hand).
    #[command(hide = true)]
    ScoreMar {
        /// Project directory (a copy of rendered-mar with its dense clouds).
        dir: PathBuf,
        /// Score OpenCV's SGBM on the project's cameras instead (run in `<dir>-sgbm`).
        #[arg(long)]
        sgbm: bool,
    },
}

#[derive(Subcommand)]
enum BenchStage {
    /// Peak memory of features on 100 MP, the dense and ortho stages of rendered-mar and
    /// `timesift dem` of 30 million points, against their budgets.
    Memory {
        /// Working folder (replaced).
        #[arg(long, default_value = "target/bench-memory")]
        out: PathBuf,
    },
    /// RANSAC homography and essential matrix against OpenCV (Python).
    Geometry {
        /// Repetitions of each estimator.
        #[arg(long, default_value_t = 20)]
        runs: usize,
    },
    /// Bundle adjustment on the BAL problems (initial/final cost, iterations, time).
    Bundle {
        /// One BAL problem file instead of all of ../shared/data/bal.
        #[arg(long)]
        problem: Option<PathBuf>,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// SIFT and LDB against OpenCV SIFT and COLMAP's CPU SIFT: correct matches between the
    /// sandpyper `mar` orthophotos of every pair of dates, and seconds per image.
    Features {
        /// Keypoint budget of the quality comparison, the same for every method.
        #[arg(long, default_value_t = 300)]
        budget: usize,
        /// Only the quality comparison.
        #[arg(long, conflicts_with = "speed_only")]
        quality_only: bool,
        /// Only the speed comparison.
        #[arg(long)]
        speed_only: bool,
        /// Also a 100 MP image: seconds and peak memory, in a fresh process.
        #[arg(long)]
        large: bool,
        /// Internal: extract one image and print seconds and peak memory as JSON.
        #[arg(long, hide = true)]
        measure_one: Option<PathBuf>,
        /// Internal: scale-space memory budget of `--measure-one`, MiB.
        #[arg(long, hide = true, default_value_t = 512)]
        memory_mib: usize,
    },
    /// Exhaustive matching of `lund` against COLMAP's CPU exhaustive matcher (2 threads).
    Matching,
    /// Images to oriented block on `lund` against COLMAP's CPU pipeline (2 threads).
    Align,
    /// Every stage's wall and CPU time, peak memory and files written on `synth scale-N` blocks
    /// (N = 100, 200, 400, 800, 1,600 images), growth exponents, check points and the DoDs'
    /// tilt on stable ground per N, a log-log plot (scale.png).
    Scale {
        /// The largest block, images (the sizes double from 100 up to it).
        #[arg(long, default_value_t = 1600)]
        max_images: usize,
        /// The smallest block run, images (a size of the doubling from 100: to add a size to an
        /// earlier run's folder, with `--reuse`).
        #[arg(long, default_value_t = 100)]
        min_images: usize,
        /// Scene seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Output folder.
        #[arg(long, default_value = "target/bench-scale")]
        out: PathBuf,
        /// Threads of every stage.
        #[arg(long, default_value_t = 2)]
        threads: usize,
        /// A stage still running after this many seconds is killed (the size's later stages
        /// are skipped).
        #[arg(long, default_value_t = 3600)]
        stage_limit: u64,
        /// Reuse the scenes already rendered in the output folder.
        #[arg(long)]
        reuse: bool,
        /// Dense clouds with the default `[dense]` settings rather than the lighter ones.
        #[arg(long)]
        full_dense: bool,
        /// A Python with pycolmap 4 (`pip install pycolmap`): COLMAP's incremental and global
        /// mappers on the same verified matches, timed and scored alike.
        #[arg(long, env = "PYCOLMAP_PYTHON")]
        colmap: Option<PathBuf>,
        /// `[align] mapper` of every block: global, incremental or auto.
        #[arg(long, default_value = "global")]
        mapper: String,
        /// Up to this N, the align stage also runs with the other mapper on the same matches.
        #[arg(long, default_value_t = 100)]
        compare_mappers_up_to: usize,
    },
    /// DoD-level co-registration on rendered-mar (two real beach surveys rendered with exact
    /// truth): each epoch's DEM and the DoD against the truth over stable ground (median, tilt
    /// of a plane), check points and the report's predicted tilt σ, per variant.
    Coreg {
        /// Variants, comma-separated: default, joined, gcps-all, truth (the true cameras).
        #[arg(long, value_delimiter = ',', default_value = "default,truth")]
        variants: Vec<String>,
        /// Output folder.
        #[arg(long, default_value = "target/bench-coreg")]
        out: PathBuf,
        /// Products with the default `[dense]` settings rather than the lighter ones.
        #[arg(long)]
        full_dense: bool,
    },
    /// Dense clouds of the synth scenes against the truth (true and align-stage cameras) and
    /// OpenCV's StereoSGBM on the same images; lund's fused points (pip install
    /// opencv-python-headless).
    Dense {
        /// Scenes (default: the seven synthetic ones, `landslide-12mp` (nine 4000 × 3000
        /// images) and `rendered-mar`, real beach texture with exact truth).
        #[arg(long, value_delimiter = ',')]
        scenes: Option<Vec<String>>,
        /// `[dense] level`.
        #[arg(long, default_value_t = 2)]
        level: u32,
        /// Scene seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Output folder.
        #[arg(long, default_value = "target/bench-dense")]
        out: PathBuf,
        /// Skip OpenCV.
        #[arg(long)]
        no_peer: bool,
        /// Skip lund.
        #[arg(long)]
        no_lund: bool,
        /// Reuse scenes already rendered and oriented in the output folder; skip the
        /// one-thread timing.
        #[arg(long)]
        reuse: bool,
        /// A `timesift` executable of another build (e.g. the last release): its dense stage
        /// runs on the same projects, timed and scored beside this build's (before / after).
        #[arg(long)]
        baseline: Option<PathBuf>,
        /// A folder with OpenMVS's `InterfaceCOLMAP` and `DensifyPointCloud` (CPU build, e.g.
        /// from `xtask/scripts/build_openmvs.sh`): the multi-view peer, on the true cameras.
        #[arg(long, env = "OPENMVS_BIN")]
        openmvs: Option<PathBuf>,
        /// Skip the align-stage cameras (true cameras only: the timing and accuracy of the
        /// dense stage alone; the synthetic scenes are not oriented).
        #[arg(long)]
        truth_only: bool,
        /// With `--reuse`: keep the synthetic scenes' depth maps, so that `[dense]` filtering
        /// and fusion options edited in their `project.toml` (and `<scene>-truth/`) redo only
        /// the clouds; the cost table then times that alone.
        #[arg(long, requires = "reuse")]
        keep_maps: bool,
    },
    /// DEMs and orthos of the synth ground scenes against the truth (sampled clouds, and the
    /// dense bench's clouds when present), gridding against GDAL's gdal_grid, gdalinfo on the
    /// products (apt-get install gdal-bin).
    Raster {
        /// Scenes (default: the six ground scenes).
        #[arg(long, value_delimiter = ',')]
        scenes: Option<Vec<String>>,
        /// Scene seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Output folder.
        #[arg(long, default_value = "target/bench-raster")]
        out: PathBuf,
        /// Where `cargo xtask bench dense` left its projects; their clouds are gridded too.
        #[arg(long, default_value = "target/bench-dense")]
        dense_dir: PathBuf,
        /// Skip gdal_grid.
        #[arg(long)]
        no_peer: bool,
    },
    /// Change detection on sandpyper `mar`: Nuth & Kääb against xdem, M3C2 against py4dgeo.
    /// Scanned film on `synth archival`: marks and interior orientations against the truth,
    /// then the orientation (and DEMs) with and without fiducial handling.
    Film {
        /// Scene seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Output folder.
        #[arg(long, default_value = "target/bench-film")]
        out: PathBuf,
        /// Orientation only (no dense clouds and DEMs).
        #[arg(long)]
        no_products: bool,
    },
    Change {
        /// Core-point spacing for M3C2, metres.
        #[arg(long, default_value_t = 1.0)]
        spacing: f64,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
}

/// Folders of ../shared/data the tests and benches read, with one file each must hold.
const DATA_SETS: [(&str, &str); 5] = [
    ("opensfm", "lund/images/01.jpg"),
    ("sandpyper-mar", "dsm/mar_20180601_dsm_resampled_1m.tif"),
    ("demcompare-srtm", "input/srtm_ref.tif"),
    ("bal", "lund-29-1863-pre.txt"),
    ("libmv-ba", "problem_01.bin"),
];

/// Registers DejaVu Sans (Debian's `fonts-dejavu-core`) as plotters' "sans-serif": without
/// fontconfig, plotters draws text only with a font handed to it.
fn register_plot_font() -> anyhow::Result<()> {
    static FONT: std::sync::OnceLock<&'static [u8]> = std::sync::OnceLock::new();
    const PATH: &str = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf";
    if FONT.get().is_none() {
        let bytes = std::fs::read(PATH)
            .with_context(|| format!("{PATH} (apt-get install fonts-dejavu-core)"))?;
        let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
        plotters::style::register_font("sans-serif", plotters::style::FontStyle::Normal, bytes)
            .map_err(|_| anyhow::anyhow!("{PATH}: not a font plotters can read"))?;
        let _ = FONT.set(bytes);
    }
    Ok(())
}

fn shared_data() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data")
}

/// The 29 `lund` photos, sorted.
fn lund_images() -> anyhow::Result<Vec<PathBuf>> {
    let dir = shared_data().join("opensfm/lund/images");
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&dir)
        .with_context(|| dir.display().to_string())?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "jpg"))
        .collect();
    paths.sort();
    Ok(paths)
}

/// Runs `colmap` with `args`; its wall time in seconds. Errors carry its last line of stderr.
fn colmap(args: &[String]) -> anyhow::Result<f64> {
    let start = std::time::Instant::now();
    let output = std::process::Command::new("colmap")
        .args(args)
        .output()
        .context("running colmap (apt-get install colmap)")?;
    let seconds = start.elapsed().as_secs_f64();
    if !output.status.success() {
        bail!(
            "colmap {} failed: {}",
            args.first().map_or("", String::as_str),
            String::from_utf8_lossy(&output.stderr)
                .lines()
                .last()
                .unwrap_or("")
        );
    }
    Ok(seconds)
}

/// Runs a peer's Python script and parses its JSON report (the whole output, or else its last
/// line, so that scripts may log before it). Errors carry the script's last line of stderr.
fn python_json(script: &std::path::Path, args: &[String]) -> anyhow::Result<serde_json::Value> {
    let output = std::process::Command::new("python3")
        .arg(script)
        .args(args)
        .output()
        .context("running python3")?;
    if !output.status.success() {
        bail!(
            "{}",
            String::from_utf8_lossy(&output.stderr)
                .lines()
                .last()
                .unwrap_or("python failed")
        );
    }
    let stdout = String::from_utf8_lossy(&output.stdout);
    serde_json::from_str(&stdout)
        .or_else(|_| serde_json::from_str(stdout.lines().last().unwrap_or("{}")))
        .context("the peer's report is not JSON")
}

/// Prints a bench's table and writes it as `<stem>.md` beside `<stem>.json` in `out`.
fn write_results(
    out: &std::path::Path,
    stem: &str,
    text: &str,
    json: &serde_json::Value,
) -> anyhow::Result<()> {
    println!("{text}");
    std::fs::write(out.join(format!("{stem}.md")), text)?;
    std::fs::write(
        out.join(format!("{stem}.json")),
        serde_json::to_string_pretty(json)?,
    )?;
    println!(
        "written: {}",
        out.join(format!("{stem}.{{md,json}}")).display()
    );
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    // The guide's tested examples (tests/integration/guide_examples.rs): parse, run nothing.
    if std::env::var_os("TIMESIFT_CHECK_ARGS").is_some() {
        println!("arguments accepted");
        return Ok(());
    }
    match cli.task {
        Task::FnLengths {
            max_lines,
            check,
            root,
        } => fn_lengths::run(
            &root.unwrap_or_else(api::workspace_root),
            max_lines,
            check.unwrap_or(usize::MAX),
            check.is_some(),
        )?,
        Task::SlurmUp => slurm::up()?,
        Task::SlurmDown => slurm::down()?,
        Task::Fuzz {
            minutes,
            targets,
            seed,
            stable,
            jobs,
        } => fuzz::run(&fuzz::FuzzOptions {
            minutes,
            targets,
            seed,
            stable,
            jobs,
        })?,
        Task::FuzzWorker {
            target,
            seconds,
            seed,
        } => fuzz::worker(&target, seconds, seed)?,
        Task::Guide { bless } => guide(bless)?,
        Task::Api { bless } => {
            let differences = api::check(&api::workspace_root(), bless)?;
            if !differences.is_empty() {
                bail!("{}", differences.join("\n"));
            }
            if bless {
                println!("api/: {} snapshots written", api::CRATES.len());
            } else {
                println!(
                    "api/: the public API of {} crates is the recorded one",
                    api::CRATES.len()
                );
            }
        }
        Task::Bench {
            stage: BenchStage::Memory { out },
        } => bench_memory::run(&out)?,
        Task::Bench {
            stage: BenchStage::Geometry { runs },
        } => bench_geometry::run(runs)?,
        Task::Bench {
            stage: BenchStage::Bundle { problem, json },
        } => bench_bundle::run(problem, json)?,
        Task::Bench {
            stage:
                BenchStage::Features {
                    budget,
                    quality_only,
                    speed_only,
                    large,
                    measure_one,
                    memory_mib,
                },
        } => match measure_one {
            Some(path) => bench_features::measure_one(&path, 8192, memory_mib)?,
            None => bench_features::run(&bench_features::FeaturesBench {
                budget,
                quality: !speed_only,
                speed: !quality_only,
                large,
            })?,
        },
        Task::Bench {
            stage: BenchStage::Matching,
        } => bench_matching::run()?,
        Task::Bench {
            stage: BenchStage::Align,
        } => bench_align::run()?,
        Task::Bench {
            stage:
                BenchStage::Scale {
                    max_images,
                    min_images,
                    seed,
                    out,
                    threads,
                    stage_limit,
                    reuse,
                    full_dense,
                    colmap,
                    mapper,
                    compare_mappers_up_to,
                },
        } => bench_scale::run(&bench_scale::ScaleBench {
            sizes: std::iter::successors(Some(100usize), |n| Some(n * 2))
                .take_while(|n| *n <= max_images)
                .filter(|n| *n >= min_images)
                .collect(),
            out,
            seed,
            threads,
            stage_limit: std::time::Duration::from_secs(stage_limit),
            reuse,
            full_dense,
            colmap,
            mapper: match mapper.as_str() {
                "incremental" => timesift::config::MapperConfig::Incremental,
                "global" => timesift::config::MapperConfig::Global,
                "auto" => timesift::config::MapperConfig::Auto,
                other => anyhow::bail!("--mapper {other}: expected global, incremental or auto"),
            },
            compare_mappers_up_to,
        })?,
        Task::Bench {
            stage:
                BenchStage::Coreg {
                    variants,
                    out,
                    full_dense,
                },
        } => bench_coreg::run_bench(&bench_coreg::CoregBench {
            variants,
            out,
            full_dense,
        })?,
        Task::Bench {
            stage:
                BenchStage::Film {
                    seed,
                    out,
                    no_products,
                },
        } => bench_film::run_bench(&bench_film::FilmBench {
            seed,
            out,
            products: !no_products,
        })?,
        Task::Bench {
            stage: BenchStage::Change { spacing, json },
        } => bench_change::run(spacing, json)?,
        Task::Bench {
            stage:
                BenchStage::Raster {
                    scenes,
                    seed,
                    out,
                    dense_dir,
                    no_peer,
                },
        } => bench_raster::run_bench(&bench_raster::RasterBench {
            scenes: scenes.unwrap_or_else(|| {
                [
                    "orchard",
                    "shore",
                    "landslide",
                    "glacier",
                    "archival",
                    "campus",
                    "landslide-12mp",
                    "rendered-mar",
                ]
                .iter()
                .map(|s| s.to_string())
                .collect()
            }),
            seed,
            out,
            dense_dir: dense_dir.is_dir().then_some(dense_dir),
            peer: !no_peer,
        })?,
        Task::Bench {
            stage:
                BenchStage::Dense {
                    scenes,
                    level,
                    seed,
                    out,
                    no_peer,
                    no_lund,
                    reuse,
                    baseline,
                    truth_only,
                    openmvs,
                    keep_maps,
                },
        } => bench_dense::run_bench(&bench_dense::DenseBench {
            scenes: scenes.unwrap_or_else(|| {
                [
                    "archival",
                    "glacier",
                    "orchard",
                    "shore",
                    "landslide",
                    "soil-pit",
                    "campus",
                    "landslide-12mp",
                    "rendered-mar",
                ]
                .iter()
                .map(|s| s.to_string())
                .collect()
            }),
            level,
            seed,
            out,
            peer: !no_peer,
            lund: !no_lund,
            reuse,
            baseline,
            truth_only,
            openmvs,
            keep_maps,
        })?,
        Task::BenchMethods {
            scenes,
            methods,
            scale,
            seed,
            out,
            no_products,
            full_dense,
            ties,
        } => bench_methods::run_bench(&bench_methods::MethodsBench {
            products: !no_products,
            full_dense,
            ties,
            scenes: scenes.unwrap_or_else(|| {
                timesift_synth::scenes::SCENES
                    .iter()
                    .map(|s| s.to_string())
                    .collect()
            }),
            methods: match methods {
                Some(names) => names.iter().map(|n| n.parse()).collect::<Result<_, _>>()?,
                None => timesift_align::Method::ALL.to_vec(),
            },
            scale,
            seeds: seed,
            out,
        })?,
        Task::Synth {
            scene,
            out,
            seed,
            scale,
            no_images,
            film,
        } => {
            let scale: timesift_synth::scenes::Scale = scale
                .parse()
                .map_err(|e: String| anyhow::anyhow!("--scale: {e}"))?;
            let mut spec = timesift_synth::scenes::build(&scene, scale, seed)?;
            if film {
                spec.scan_every_epoch();
            }
            let start = std::time::Instant::now();
            let written = timesift_synth::writer::write_scene(
                &spec,
                &out,
                &timesift_synth::writer::WriteOptions { images: !no_images },
            )?;
            let seconds = start.elapsed().as_secs_f64();
            println!(
                "{scene}: {} epochs, {} images ({:.1} MP rendered), {} markers -> {} in {seconds:.1} s{}",
                spec.epochs.len(),
                written.images,
                written.megapixels,
                written.markers,
                out.display(),
                if written.megapixels > 0.0 {
                    format!(" ({:.2} s/MP)", seconds / written.megapixels)
                } else {
                    String::new()
                }
            );
        }
        Task::ScoreMar { dir, sgbm } => {
            print!("{}", bench_dense_mar::score_project(&dir, sgbm)?);
        }
        Task::RunStage { dir, stage } => {
            let project = timesift::Project::load(&dir)?;
            timesift::stages::run(&project, Some(stage), Some(stage))?;
        }
        Task::ScalePeers { dir, python } => {
            for row in bench_scale_colmap::run_peers(&dir, &python, 2)? {
                println!("{}", serde_json::to_string(&row)?);
            }
        }
        Task::ScoreAlign { dir } => {
            for (epoch, rmse) in bench_scale::score_align(&dir)? {
                match rmse {
                    Some([e, n, h]) => {
                        println!("{epoch}: check points dE {e:.3} dN {n:.3} dH {h:.3} GSD")
                    }
                    None => println!("{epoch}: no check point"),
                }
            }
        }
        Task::RunDense { dir } => {
            let project = timesift::Project::load(&dir)?;
            timesift::stages::run_stage(&project, timesift::stages::Stage::Dense)?;
        }
        Task::Data => {
            let root = shared_data();
            let mut missing = Vec::new();
            for (set, file) in DATA_SETS {
                let path = root.join(set).join(file);
                if path.is_file() {
                    let len = std::fs::metadata(&path)
                        .with_context(|| path.display().to_string())?
                        .len();
                    println!("ok       {set:<16} {file} ({len} bytes)");
                } else {
                    println!("MISSING  {set:<16} {}", path.display());
                    missing.push(set);
                }
            }
            if !missing.is_empty() {
                bail!("shared data missing: {}", missing.join(", "));
            }
        }
    }
    Ok(())
}

/// `cargo xtask guide`: the reference pages are made by the test that checks them
/// (tests/integration/guide_reference.rs), so there is one generator; then `mdbook build`.
fn guide(bless: bool) -> anyhow::Result<()> {
    let root = api::workspace_root();
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut test = std::process::Command::new(cargo);
    test.args([
        "test",
        "-p",
        "timesift",
        "--test",
        "integration",
        "guide_reference",
    ])
    .current_dir(&root);
    if bless {
        test.env("TIMESIFT_BLESS", "1");
    }
    if !test.status()?.success() {
        bail!("the guide's reference pages are stale: run `cargo xtask guide --bless`");
    }
    match std::process::Command::new("mdbook")
        .args(["build", "docs/guide"])
        .current_dir(&root)
        .status()
    {
        Ok(status) if status.success() => println!("built docs/guide/book/index.html"),
        Ok(_) => bail!("mdbook build docs/guide failed"),
        Err(_) => {
            println!("mdbook is not installed (cargo install mdbook): the book was not built")
        }
    }
    Ok(())
}
