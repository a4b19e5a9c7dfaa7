//! `timesift dem`: grids any point cloud (LAS/LAZ, made by timesift or any other software) into a
//! DEM GeoTIFF with its count, spread and filled-cell companions, on a lattice of a given cell
//! size or on the exact grid of another GeoTIFF (`--like`), so that it stacks with it.

use std::path::{Path, PathBuf};
use std::time::Instant;

use timesift_io::coords::Crs;
use timesift_io::pointcloud::read_las_positions;
use timesift_raster::{Bounds, CellHeight, DemOptions, Lattice, grid_cloud};

use crate::ProjectError;
use crate::stages::write_dem_files;

/// The cell statistic.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DemMethod {
    /// Median of the cell's points.
    Median,
    /// Highest point of the cell (surface model of tall objects).
    Max,
    /// Inverse-distance mean within `--idw-radius` cells.
    Idw,
}

/// What `timesift dem` was asked for (also its command-line arguments).
#[derive(Debug, Clone, clap::Args)]
pub struct DemRequest {
    /// The point cloud (.las or .laz).
    pub cloud: PathBuf,
    /// Cell size in metres; the lattice covers the cloud with edges on multiples of it.
    #[arg(long)]
    pub cell: Option<f64>,
    /// Use the grid (origin, cell, size) and, when the cloud has none, the CRS of this GeoTIFF.
    #[arg(long)]
    pub like: Option<PathBuf>,
    /// Output GeoTIFF; `<stem>_count.tif`, `<stem>_std.tif`, `<stem>_filled.tif` and a
    /// hillshade `<stem>.png` are written beside it.
    #[arg(long)]
    pub out: PathBuf,
    /// Cell statistic.
    #[arg(long, value_enum, default_value = "median")]
    pub method: DemMethod,
    /// Search radius of `idw`, in cells.
    #[arg(long, default_value_t = 1.5)]
    pub idw_radius: f64,
    /// Least points per cell.
    #[arg(long, default_value_t = 1)]
    pub min_points: usize,
    /// Interpolate holes up to this many cells across (0: none).
    #[arg(long, default_value_t = 0)]
    pub max_gap: usize,
}

/// What `timesift dem` did.
#[derive(Debug, Clone, PartialEq)]
pub struct DemSummary {
    /// Points read.
    pub points: usize,
    /// Columns and rows of the DEM.
    pub size: (usize, usize),
    /// Cells with a height (measured or filled).
    pub cells_with_height: usize,
    /// Cells filled by interpolation.
    pub cells_filled: usize,
    /// Seconds spent reading the cloud.
    pub reading_seconds: f64,
    /// Seconds spent gridding (reading and writing excluded).
    pub gridding_seconds: f64,
    /// Seconds spent writing the rasters.
    pub writing_seconds: f64,
    /// Files written.
    pub outputs: Vec<PathBuf>,
}

fn beside(out: &Path, suffix: &str, ext: &str) -> PathBuf {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "dem".into());
    out.with_file_name(format!("{stem}{suffix}.{ext}"))
}

/// Grids the cloud and writes the DEM and its companions.
pub fn dem(request: &DemRequest) -> Result<DemSummary, ProjectError> {
    let start = Instant::now();
    let cloud = read_las_positions(&request.cloud)?;
    let reading_seconds = start.elapsed().as_secs_f64();
    let (lattice, like_crs) = match (&request.like, request.cell) {
        (Some(_), Some(_)) | (None, None) => {
            return Err(ProjectError::Path {
                path: request.out.clone(),
                message: "give either --cell C or --like GRID.tif (exactly one)".into(),
            });
        }
        (Some(like), None) => {
            let grid = timesift_io::geotiff::read_grid(like)?;
            let t = grid.georef.transform;
            let lattice = Lattice::with_cells(
                t.origin_x,
                t.origin_y,
                t.pixel_width,
                -t.pixel_height,
                grid.width,
                grid.height,
            )
            .map_err(|e| ProjectError::Path {
                path: like.clone(),
                message: e.to_string(),
            })?;
            (lattice, Some(grid.georef.crs))
        }
        (None, Some(cell)) => {
            let bounds =
                cloud_bounds(&cloud.positions, cell).ok_or_else(|| ProjectError::Path {
                    path: request.cloud.clone(),
                    message: "no finite point: nothing to grid".into(),
                })?;
            let lattice = Lattice::covering(&bounds, cell).map_err(|e| ProjectError::Path {
                path: request.cloud.clone(),
                message: format!("--cell {cell}: {e}"),
            })?;
            (lattice, None)
        }
    };
    let crs = match (cloud.crs, like_crs) {
        (Crs::Local, Some(c)) => c,
        (c, _) => c,
    };
    let height = match request.method {
        DemMethod::Median => CellHeight::Median,
        DemMethod::Max => CellHeight::Max,
        DemMethod::Idw => CellHeight::InverseDistance {
            radius: request.idw_radius * lattice.cell(),
            power: 2.0,
        },
    };
    let options = DemOptions {
        height,
        min_points: request.min_points.max(1),
        max_gap: request.max_gap,
    };
    let start = Instant::now();
    let dem = grid_cloud(&cloud.positions, &lattice, &options).map_err(|e| ProjectError::Path {
        path: request.cloud.clone(),
        message: e.to_string(),
    })?;
    let gridding_seconds = start.elapsed().as_secs_f64();
    let outputs = [
        request.out.clone(),
        beside(&request.out, "_count", "tif"),
        beside(&request.out, "_std", "tif"),
        beside(&request.out, "_filled", "tif"),
    ];
    let preview = beside(&request.out, "", "png");
    let start = Instant::now();
    write_dem_files(&dem, crs, &outputs, &preview)?;
    let writing_seconds = start.elapsed().as_secs_f64();
    let mut written = outputs.to_vec();
    written.push(preview);
    Ok(DemSummary {
        points: cloud.positions.len(),
        size: (lattice.width(), lattice.height()),
        cells_with_height: dem.valid_cells(),
        cells_filled: dem.filled.iter().filter(|f| **f).count(),
        reading_seconds,
        gridding_seconds,
        writing_seconds,
        outputs: written,
    })
}

/// The x, y extent of the finite points, at least half a cell on each side of a lone point.
fn cloud_bounds(points: &[[f64; 3]], cell: f64) -> Option<Bounds> {
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for p in points.iter().filter(|p| p.iter().all(|v| v.is_finite())) {
        b[0] = b[0].min(p[0]);
        b[1] = b[1].min(p[1]);
        b[2] = b[2].max(p[0]);
        b[3] = b[3].max(p[1]);
    }
    if !b[0].is_finite() {
        return None;
    }
    let pad = |lo: f64, hi: f64| {
        if hi > lo {
            (lo, hi)
        } else {
            (lo - 0.5 * cell, hi + 0.5 * cell)
        }
    };
    let (x0, x1) = pad(b[0], b[2]);
    let (y0, y1) = pad(b[1], b[3]);
    // A point on the east or south edge belongs to the cell beyond it: reach past it.
    let beyond = 1e-6 * cell;
    Bounds::new(x0, y0 - beyond, x1 + beyond, y1).ok()
}
