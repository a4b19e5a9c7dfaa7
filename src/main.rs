//! The `timesift` command line: argument parsing and one error report; the work is in the library.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use timesift::commands::init::InitOptions;
use timesift::commands::{compare, dem, features, info, init};
use timesift::config::Coregistration;
use timesift::stages::Stage;
use timesift::{Project, stages};
use timesift_change::icp::IcpModel;
use timesift_change::m3c2::{Aggregation, M3c2Params};
use tracing_subscriber::filter::{LevelFilter, Targets};
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;

/// Prints a line of a command's result. A closed pipe (`timesift … | head`) ends the program
/// quietly, as Unix tools do, instead of panicking as `println!` would.
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        if let Err(e) = writeln!(std::io::stdout(), $($arg)*) {
            if e.kind() == std::io::ErrorKind::BrokenPipe {
                std::process::exit(0);
            }
            eprintln!("error: cannot write to standard output: {e}");
            std::process::exit(1);
        }
    }};
}

#[derive(Parser)]
#[command(
    name = "timesift",
    version,
    about = "Multi-temporal photogrammetry: one block for all epochs"
)]
struct Cli {
    /// More log output (repeat for more).
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    verbose: u8,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Write project.toml from the folders of images/ (one epoch per folder) and the images' EXIF.
    Init {
        /// Project directory holding images/<epoch>/.
        dir: PathBuf,
        /// Overwrite an existing project.toml.
        #[arg(long)]
        force: bool,
    },
    /// Show epochs, images, camera groups, priors (projected) and the outputs present.
    Info {
        /// Project directory.
        dir: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Run the pipeline stages in order.
    Run {
        /// Project directory.
        dir: PathBuf,
        /// First stage to run.
        #[arg(long, value_enum)]
        from: Option<Stage>,
        /// Last stage to run.
        #[arg(long, value_enum)]
        to: Option<Stage>,
        /// No progress bars and no per-stage lines; errors still go to standard error.
        #[arg(long, short)]
        quiet: bool,
        /// Where the units of work run: here (`local`) or as Slurm job arrays (`slurm`).
        #[arg(long, value_enum, default_value_t = Executor::Local)]
        executor: Executor,
        /// With `--executor slurm`: print the arrays, tasks, memory and files; submit nothing.
        #[arg(long)]
        dry_run: bool,
        #[command(flatten)]
        cluster: ClusterArgs,
    },
    /// Run one unit of work of a step (what a cluster task runs): `--part i/n`.
    Task {
        /// The step (`timesift run --executor slurm --dry-run` lists them).
        step: String,
        /// Project directory.
        dir: PathBuf,
        /// Unit i of n (1-based).
        #[arg(long, default_value = "1/1")]
        part: timesift::tasks::Part,
    },
    /// Show per step which units are complete, running, queued, failed or missing.
    Status {
        /// Project directory.
        dir: PathBuf,
    },
    /// Keypoints and descriptors of one image, written in the text format of docs/design.md.
    Features(features::FeaturesRequest),
    /// Grid any point cloud (LAS/LAZ) into a DEM GeoTIFF, on a cell size or another raster's grid.
    Dem(dem::DemRequest),
    /// Render a small synthetic project where the ground changed (landslide), run every stage on
    /// it and print the orientation, DEM, DoD and volume figures against the truth.
    Demo {
        /// Where to write the project (empty or new). Default: ./timesift-demo.
        dir: Option<PathBuf>,
    },
    /// Measure the fiducial marks of every scanned film image and report them (out/fiducials.csv,
    /// out/fiducials.json, a contact sheet out/fiducials.png); `run` does this when needed.
    Fiducials {
        /// Project directory (a [[camera]] with [camera.fiducials]).
        dir: PathBuf,
    },
    /// Write the cameras, calibrations and sparse points for Metashape, COLMAP or OpenSfM/ODM.
    Export {
        /// Project directory (after the align stage).
        dir: PathBuf,
        /// Target format.
        #[arg(long, value_enum)]
        format: timesift::commands::export::ExportFormat,
        /// Output folder. Default: DIR/out/export/<format>/.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Compare two DEMs (GeoTIFF: DoD, co-registration, statistics, LoD, volumes) or two point
    /// clouds (LAS/LAZ: ICP, M3C2), made by timesift or any other software.
    Compare(Box<CompareArgs>),
    /// Print a shell completion script, e.g. `timesift completions bash >
    /// ~/.local/share/bash-completion/completions/timesift`.
    Completions {
        /// The shell.
        #[arg(value_enum)]
        shell: clap_complete::Shell,
    },
    /// Write the manual pages (timesift.1 and one per command, timesift-run.1, ...) into a folder,
    /// e.g. `timesift man ~/.local/share/man/man1`.
    Man {
        /// Folder to write the pages into (made if missing).
        dir: PathBuf,
    },
}

#[derive(clap::Args)]
struct CompareArgs {
    /// The earlier DEM or cloud (the reference).
    a: PathBuf,
    /// The later DEM or cloud.
    b: PathBuf,
    /// Output folder.
    #[arg(long, default_value = "compare")]
    out: PathBuf,
    /// Stable areas: polygons ([name,]WKT lines, as stable.csv) or, for DEMs, a mask GeoTIFF.
    #[arg(long)]
    stable: Option<PathBuf>,
    /// DEMs: a value to treat as nodata besides the declared one (e.g. -10000).
    #[arg(long, allow_hyphen_values = true)]
    nodata: Option<f64>,
    /// DEMs: co-registration of b onto a before differencing.
    #[arg(long, value_enum, default_value = "none")]
    coregister: CoregisterArg,
    /// DEMs: σ of a and of b (m) for the LoD95; default 1.96 × the stable-area NMAD.
    #[arg(long, num_args = 2, value_names = ["SIGMA_A", "SIGMA_B"])]
    sigma: Option<Vec<f64>>,
    /// DEMs: polygons (or a mask GeoTIFF) bounding the volume computation.
    #[arg(long)]
    region: Option<PathBuf>,
    /// DEMs: check points (CSV name,x,y,z): DEM height residuals of both DEMs.
    #[arg(long)]
    checkpoints: Option<PathBuf>,
    /// Clouds: register b onto a by ICP on the stable areas first.
    #[arg(long, value_enum)]
    icp: Option<IcpArg>,
    /// Clouds: M3C2 normal radius (m); repeat for multi-scale normals.
    #[arg(long = "normal-radius", default_values_t = [2.0])]
    normal_radius: Vec<f64>,
    /// Clouds: M3C2 cylinder radius (m).
    #[arg(long, default_value_t = 1.0)]
    cylinder_radius: f64,
    /// Clouds: M3C2 half-length of the cylinder (m).
    #[arg(long, default_value_t = 5.0)]
    max_depth: f64,
    /// Clouds: registration error added to the LoD (m); default the ICP RMS, or 0.
    #[arg(long)]
    registration_error: Option<f64>,
    /// Clouds: core-point spacing (m).
    #[arg(long, default_value_t = 1.0)]
    core_spacing: f64,
    /// Clouds: median and inter-quartile range instead of mean and standard deviation.
    #[arg(long)]
    median: bool,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum CoregisterArg {
    None,
    Vertical,
    NuthKaab,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum IcpArg {
    Rigid,
    Similarity,
}

/// Where `timesift run` runs the units of work.
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Executor {
    /// In this process, with every core.
    Local,
    /// As Slurm job arrays over the shared project directory.
    Slurm,
}

/// The `[cluster]` keys on the command line (they override project.toml's).
#[derive(clap::Args)]
struct ClusterArgs {
    /// Slurm partition.
    #[arg(long)]
    partition: Option<String>,
    /// Slurm account.
    #[arg(long)]
    account: Option<String>,
    /// Time limit per task (e.g. 04:00:00).
    #[arg(long)]
    time: Option<String>,
    /// CPUs per task.
    #[arg(long)]
    cpus_per_task: Option<usize>,
    /// Most tasks of one array running at once.
    #[arg(long)]
    max_array: Option<usize>,
    /// A further sbatch argument (repeat for more), e.g. --sbatch-arg=--qos=long.
    #[arg(long = "sbatch-arg", allow_hyphen_values = true)]
    sbatch_args: Vec<String>,
}

/// A panic is a bug of timesift's, never the user's input: it is reported in one line, as
/// errors are, with where it happened (the full report with `RUST_BACKTRACE=1`). Panics of a
/// third-party decoder on corrupt data are not printed: they return as errors naming the file
/// (`timesift_io::decoder_guard`).
fn install_panic_report() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if timesift_io::decoder_guard::guard_active() {
            return;
        }
        if std::env::var_os("RUST_BACKTRACE").is_some_and(|v| v != "0") {
            return default(info);
        }
        let message = timesift_io::decoder_guard::panic_text(info.payload());
        let place = info
            .location()
            .map(|l| format!(" at {}:{}", l.file(), l.line()))
            .unwrap_or_default();
        eprintln!(
            "error: internal error{place}: {}; please report it with the command that caused \
             it (RUST_BACKTRACE=1 prints where)",
            message.replace('\n', " ")
        );
    }));
}

/// An error and its causes in one line, each cause once: an error that already shows its
/// cause's text (`path: No such file or directory`) is not followed by it again.
fn one_line(e: &anyhow::Error) -> String {
    let mut parts: Vec<String> = Vec::new();
    for cause in e.chain() {
        let text = cause.to_string().replace('\n', " ");
        if !parts.last().is_some_and(|shown| shown.contains(&text)) {
            parts.push(text);
        }
    }
    parts.join(": ")
}

fn main() -> ExitCode {
    install_panic_report();
    let cli = Cli::parse();
    // The guide's tested examples (tests/integration/guide_examples.rs) check that every
    // documented command line parses: with this variable set, parsing is all that happens.
    if std::env::var_os("TIMESIFT_CHECK_ARGS").is_some() {
        say!("arguments accepted");
        return ExitCode::SUCCESS;
    }
    let level = match cli.verbose {
        0 => LevelFilter::WARN,
        1 => LevelFilter::INFO,
        _ => LevelFilter::DEBUG,
    };
    // `RUST_LOG` takes per-crate levels (`info,timesift_dense=debug`); a value it cannot parse
    // falls back to the level of `-v`. (Targets, not EnvFilter: no regex engine in the binary.)
    let filter = std::env::var("RUST_LOG")
        .ok()
        .and_then(|spec| spec.parse::<Targets>().ok())
        .unwrap_or_else(|| Targets::new().with_default(level));
    tracing_subscriber::registry()
        .with(tracing_subscriber::fmt::layer().with_writer(std::io::stderr))
        .with(filter)
        .init();
    match run(cli.command) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", one_line(&e));
            ExitCode::FAILURE
        }
    }
}

fn run(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Init { dir, force } => {
            let summary = init::init(&dir, InitOptions { overwrite: force })?;
            say!("wrote {}", dir.join("project.toml").display());
            for (name, n) in &summary.epochs {
                say!("  epoch {name}: {n} images");
            }
            say!(
                "  crs {} ({} images with EXIF GPS)",
                summary.crs,
                summary.images_with_gps
            );
        }
        Command::Info { dir, json } => {
            let project = Project::load(&dir)?;
            let report = info::info(&project)?;
            if json {
                say!("{}", serde_json::to_string_pretty(&report)?);
            } else {
                say!("{}", report.to_text().trim_end());
            }
        }
        Command::Run {
            dir,
            from,
            to,
            quiet,
            executor,
            dry_run,
            cluster,
        } => match executor {
            Executor::Local if dry_run => {
                anyhow::bail!("--dry-run plans a cluster run: add --executor slurm")
            }
            Executor::Local => run_pipeline(&dir, from, to, quiet)?,
            Executor::Slurm => submit_pipeline(&dir, from, to, dry_run, &cluster)?,
        },
        Command::Task { step, dir, part } => {
            let project = Project::load(&dir)?;
            let project = timesift::Project {
                progress: timesift::progress::Progress::Hidden,
                ..project
            };
            match timesift::tasks::run_task(&project, &step, part)? {
                timesift::tasks::UnitOutcome::AlreadyComplete => {
                    say!("{step} {part}: already complete");
                }
                timesift::tasks::UnitOutcome::Ran { outputs, seconds } => {
                    say!("{step} {part}: {} files in {seconds:.1} s", outputs.len());
                }
            }
        }
        Command::Status { dir } => {
            let project = Project::load(&dir)?;
            let options = plan_options(&project, &ClusterArgs::none());
            let plan = timesift::tasks::cluster_plan(&project, &options)?;
            let submission = timesift::tasks::slurm::Submission::read(&project);
            let jobs = timesift::tasks::slurm::JobStates::query(
                &submission.as_ref().map(|s| s.jobs()).unwrap_or_default(),
            );
            let steps = timesift::tasks::status(&project, &plan, submission.as_ref(), &jobs);
            say!("{}", timesift::tasks::status_table(&steps).trim_end());
            for note in &jobs.notes {
                say!("note: {note}");
            }
        }
        Command::Features(request) => {
            let start = std::time::Instant::now();
            let result = features::features(&request)?;
            say!(
                "{} keypoints -> {} in {:.2} s",
                result.keypoints.len(),
                request.out.display(),
                start.elapsed().as_secs_f64()
            );
        }
        Command::Dem(request) => grid_cloud(&request)?,
        Command::Compare(args) => compare(*args)?,
        Command::Completions { shell } => {
            use clap::CommandFactory;
            let mut out = Vec::new();
            clap_complete::generate(shell, &mut Cli::command(), "timesift", &mut out);
            say!("{}", String::from_utf8_lossy(&out).trim_end());
        }
        Command::Man { dir } => {
            use clap::CommandFactory;
            std::fs::create_dir_all(&dir)
                .map_err(|e| anyhow::anyhow!("{}: cannot make the folder: {e}", dir.display()))?;
            clap_mangen::generate_to(Cli::command(), &dir)
                .map_err(|e| anyhow::anyhow!("{}: cannot write the pages: {e}", dir.display()))?;
            let mut pages: Vec<String> = std::fs::read_dir(&dir)?
                .filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.starts_with("timesift") && n.ends_with(".1"))
                .collect();
            pages.sort();
            say!(
                "wrote {} manual pages in {}: {}",
                pages.len(),
                dir.display(),
                pages.join(" ")
            );
        }
        Command::Export { dir, format, out } => {
            let project = Project::load(&dir)?;
            for path in timesift::commands::export::export(&project, format, out.as_deref())? {
                say!("wrote {}", path.display());
            }
        }
        Command::Fiducials { dir } => {
            let project = Project::load(&dir)?;
            let outcome = timesift::commands::fiducials::fiducials(&project)?;
            say!(
                "{}",
                timesift::commands::fiducials::summary_table(&outcome).trim_end()
            );
            let layout = project.layout();
            say!(
                "{}; wrote {}, {} and {}",
                outcome.summary(),
                layout.fiducials_csv().display(),
                layout.fiducials_json().display(),
                layout.fiducials_sheet().display()
            );
            timesift::commands::fiducials::all_oriented(&outcome)?;
        }
        Command::Demo { dir } => {
            let dir = dir.unwrap_or_else(|| PathBuf::from("timesift-demo"));
            say!("{}", timesift::commands::demo::demo(&dir)?.trim_end());
        }
    }
    Ok(())
}

/// `timesift run`: the stages from `from` to `to`, a line per stage, then the products.
fn run_pipeline(
    dir: &std::path::Path,
    from: Option<stages::Stage>,
    to: Option<stages::Stage>,
    quiet: bool,
) -> anyhow::Result<()> {
    let mut project = Project::load(dir)?;
    let _lock = timesift::tasks::ProjectLock::acquire(&project, "timesift run")?;
    // Tasks of a cluster submission write the same files: not while Slurm holds any.
    timesift::tasks::slurm::refuse_while_queued(&project)?;
    if quiet {
        project.progress = timesift::progress::Progress::Hidden;
    }
    let start = std::time::Instant::now();
    let outcomes = stages::run_with(&project, from, to, &mut |o| {
        if !quiet {
            eprintln!("{:<9} {:>7.1} s  {}", o.stage.name(), o.seconds, o.summary);
        }
    })?;
    if !quiet {
        say!(
            "{} stages in {:.1} s; products:",
            outcomes.len(),
            start.elapsed().as_secs_f64()
        );
        let out_dir = project.layout().out_dir();
        for o in &outcomes {
            for path in o.stage.implementation().outputs(&project) {
                if path.starts_with(&out_dir) && path.exists() {
                    say!("  {:<9} {}", o.stage.name(), path.display());
                }
            }
        }
    }
    Ok(())
}

impl ClusterArgs {
    fn none() -> ClusterArgs {
        ClusterArgs {
            partition: None,
            account: None,
            time: None,
            cpus_per_task: None,
            max_array: None,
            sbatch_args: Vec::new(),
        }
    }
}

/// The split of the cluster plan: `[cluster]`, with the command line's CPUs.
fn plan_options(project: &Project, args: &ClusterArgs) -> timesift::tasks::PlanOptions {
    let c = &project.config.cluster;
    timesift::tasks::PlanOptions {
        cpus_per_task: args.cpus_per_task.unwrap_or(c.cpus_per_task),
        images_per_task: c.images_per_task,
        pairs_per_task: c.pairs_per_task,
        views_per_task: c.views_per_task,
        ortho_megapixels_per_task: c.ortho_megapixels_per_task,
    }
}

/// `timesift run --executor slurm`: the stages' missing units submitted as job arrays (or,
/// with `--dry-run`, only planned), under the project's lock.
fn submit_pipeline(
    dir: &std::path::Path,
    from: Option<stages::Stage>,
    to: Option<stages::Stage>,
    dry_run: bool,
    args: &ClusterArgs,
) -> anyhow::Result<()> {
    use timesift::tasks::slurm;
    let start = std::time::Instant::now();
    let project = Project::load(dir)?;
    let _lock = if dry_run {
        None
    } else {
        Some(timesift::tasks::ProjectLock::acquire(
            &project,
            "timesift run --executor slurm (submitting)",
        )?)
    };
    let mut options = slurm::SlurmOptions::from_config(&project.config.cluster);
    options.partition = args.partition.clone().or(options.partition);
    options.account = args.account.clone().or(options.account);
    options.time = args.time.clone().or(options.time);
    options.cpus_per_task = args.cpus_per_task.unwrap_or(options.cpus_per_task);
    options.max_array = args.max_array.or(options.max_array);
    options.sbatch_args.extend(args.sbatch_args.iter().cloned());
    let plan = timesift::tasks::cluster_plan(&project, &plan_options(&project, args))?;
    let stages = stages::stage_range(from, to)?;
    let steps = plan.of_stages(&stages);
    let (max_array_size, asked) = match slurm::max_array_size() {
        Some(n) => (n, true),
        None if dry_run => (slurm::DEFAULT_MAX_ARRAY_SIZE, false),
        None => anyhow::bail!(
            "cannot ask Slurm for its configuration (`scontrol show config` failed): is this a \
             Slurm login node?"
        ),
    };
    let report = slurm::submit(&project, &plan, &steps, &options, max_array_size, dry_run)?;
    say!("{}", report.table.trim_end());
    if !asked {
        say!(
            "note: MaxArraySize assumed {max_array_size} (Slurm's default; scontrol not reachable)"
        );
    }
    if dry_run {
        say!(
            "planned {} steps in {:.2} s; nothing submitted",
            steps.len(),
            start.elapsed().as_secs_f64()
        );
    } else {
        for s in &report.submission.steps {
            for a in &s.arrays {
                say!(
                    "submitted {} as job {} ({} tasks)",
                    s.step,
                    a.job,
                    a.tasks.len()
                );
            }
        }
        say!(
            "follow with: timesift status {}  (logs in {})",
            dir.display(),
            project.layout().slurm_dir().join("logs").display()
        );
    }
    Ok(())
}

/// `timesift dem`: one cloud gridded, with the time of each step.
fn grid_cloud(request: &dem::DemRequest) -> anyhow::Result<()> {
    let r = dem::dem(request)?;
    say!(
        "{} points -> {} × {} cells, {} with a height ({} filled), gridded in {:.3} s \
         (read in {:.3} s, written in {:.3} s)",
        r.points,
        r.size.0,
        r.size.1,
        r.cells_with_height,
        r.cells_filled,
        r.gridding_seconds,
        r.reading_seconds,
        r.writing_seconds
    );
    for f in &r.outputs {
        say!("wrote {}", f.display());
    }
    Ok(())
}

fn is_cloud(path: &std::path::Path) -> Option<bool> {
    let ext = path.extension()?.to_string_lossy().to_ascii_lowercase();
    match ext.as_str() {
        "tif" | "tiff" => Some(false),
        "las" | "laz" => Some(true),
        _ => None,
    }
}

fn compare(args: CompareArgs) -> anyhow::Result<()> {
    let kind = |p: &PathBuf| {
        is_cloud(p).ok_or_else(|| {
            anyhow::anyhow!(
                "{}: expected a DEM (.tif, .tiff) or a point cloud (.las, .laz)",
                p.display()
            )
        })
    };
    let (cloud_a, cloud_b) = (kind(&args.a)?, kind(&args.b)?);
    if cloud_a != cloud_b {
        anyhow::bail!(
            "{} and {}: one is a DEM and the other a point cloud; compare like with like",
            args.a.display(),
            args.b.display()
        );
    }
    if cloud_a {
        let options = compare::CloudCompareOptions {
            stable: args.stable,
            icp: args.icp.map(|m| match m {
                IcpArg::Rigid => IcpModel::Rigid,
                IcpArg::Similarity => IcpModel::Similarity,
            }),
            m3c2: M3c2Params {
                normal_radii: args.normal_radius,
                cylinder_radius: args.cylinder_radius,
                max_depth: args.max_depth,
                registration_error: 0.0,
                aggregation: if args.median {
                    Aggregation::Median
                } else {
                    Aggregation::Mean
                },
                ..M3c2Params::default()
            },
            registration_error: args.registration_error,
            core_spacing: args.core_spacing,
        };
        let report = compare::compare_clouds(&args.a, &args.b, &args.out, &options)?;
        say!("{}", report.to_string().trim_end());
    } else {
        let options = compare::DemCompareOptions {
            extra_nodata: args.nodata,
            stable: args.stable,
            coregistration: match args.coregister {
                CoregisterArg::None => Coregistration::None,
                CoregisterArg::Vertical => Coregistration::Vertical,
                CoregisterArg::NuthKaab => Coregistration::NuthKaab,
            },
            sigmas: args.sigma.map(|s| (s[0], s[1])),
            region: args.region,
            checkpoints: match &args.checkpoints {
                Some(path) => compare::read_checkpoints(path)?,
                None => Vec::new(),
            },
        };
        let report = compare::compare_dems(&args.a, &args.b, &args.out, &options)?;
        for w in &report.warnings {
            eprintln!("warning: {w}");
        }
        say!("{}", report.to_string().trim_end());
    }
    Ok(())
}
