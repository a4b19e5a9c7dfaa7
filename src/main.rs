//! The `timesift` command line: argument parsing and one error report; the work is in the library.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use timesift::init::InitOptions;
use timesift::stages::Stage;
use timesift::{Project, info, init, stages};

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
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let level = match cli.verbose {
        0 => "warn",
        1 => "info",
        _ => "debug",
    };
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(level)),
        )
        .with_writer(std::io::stderr)
        .init();
    match run(cli.command) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // One line: the chain of causes joined.
            eprintln!("error: {}", format!("{e:#}").replace('\n', " "));
            ExitCode::FAILURE
        }
    }
}

fn run(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Init { dir, force } => {
            let summary = init::init(&dir, InitOptions { overwrite: force })?;
            println!("wrote {}", dir.join("project.toml").display());
            for (name, n) in &summary.epochs {
                println!("  epoch {name}: {n} images");
            }
            println!(
                "  crs {} ({} images with EXIF GPS)",
                summary.crs, summary.images_with_gps
            );
        }
        Command::Info { dir, json } => {
            let project = Project::load(&dir)?;
            let report = info::info(&project)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&report)?);
            } else {
                print!("{}", report.to_text());
            }
        }
        Command::Run { dir, from, to } => {
            let project = Project::load(&dir)?;
            stages::run(&project, from, to)?;
        }
    }
    Ok(())
}
