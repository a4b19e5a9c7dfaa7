//! The `dem` stage: the project's one lattice (`out/grid.json`), then per epoch the dense cloud
//! gridded onto it: `dem.tif` with `dem_count.tif`, `dem_std.tif`, `dem_filled.tif` and a
//! hillshade preview `dem.png`, all on the same cells for every epoch.
//!
//! The lattice is made once, from the `[raster]` lattice keys, the epochs' footprints (their
//! dense clouds' extents) and ground sample distances, and kept while those keys and the epochs
//! are unchanged, so that products of later runs still stack on earlier ones. An epoch's DEM is
//! redone only when its cloud, the lattice or the gridding options change
//! (`work/raster/<epoch>.dem.json`).

use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::time::Instant;

use timesift_change::grid::DEM_NODATA;
use timesift_core::Camera;
use timesift_io::coords::Crs;
use timesift_io::geotiff::{GeoRaster, GeoReference, GeoTransform, write_f32, write_u8};

use super::product_styles;
use timesift_io::pointcloud::read_las_positions;
use timesift_raster::{Bounds, EpochFootprint, Lattice, ProjectGrid, grid_cloud, plan_grid};

use super::cache::file_stamp;
use super::cache::stage_error;
use super::dense_inputs;
use super::{PipelineStage, Stage};
use crate::report::{
    GridFile, RasterReport, read_json, read_sealed_json, write_json, write_sealed_json,
};
use crate::{Project, ProjectError};
use timesift_dense::EpochInput;

/// Version of the gridding, part of each DEM's settings.
const DEM_ALGORITHM: u32 = 1;

/// Fraction of a cloud's points left out on each side of its footprint: a few stray points
/// (sky, reflections) must not stretch every epoch's lattice.
const FOOTPRINT_TRIM: f64 = 0.0005;

/// The `dem` stage.
pub(super) struct DemStage;

impl PipelineStage for DemStage {
    fn stage(&self) -> Stage {
        Stage::Dem
    }
    fn inputs(&self, project: &Project) -> Vec<(PathBuf, Stage)> {
        let layout = project.layout();
        let mut inputs = vec![
            (layout.cameras_json(), Stage::Align),
            (layout.colmap_dir().join("points3D.txt"), Stage::Align),
        ];
        inputs.extend(
            project
                .epochs
                .iter()
                .map(|e| (layout.dense_cloud(&e.name), Stage::Dense)),
        );
        inputs
    }
    fn outputs(&self, project: &Project) -> Vec<PathBuf> {
        let layout = project.layout();
        let mut out = vec![layout.grid_json(), layout.raster_report()];
        for e in &project.epochs {
            out.extend([
                layout.dem(&e.name),
                layout.dem_count(&e.name),
                layout.dem_std(&e.name),
                layout.dem_filled(&e.name),
                layout.dem_preview(&e.name),
            ]);
        }
        out
    }
    fn run(&self, project: &Project) -> Result<String, ProjectError> {
        let report = dem_stage(project)?;
        let grid = read_json::<GridFile>(&project.layout().grid_json())?;
        Ok(format!(
            "DEMs of {} epochs on {} × {} cells of {} m",
            report.epochs.len(),
            grid.size[0],
            grid.size[1],
            grid.dem_cell
        ))
    }
}

/// The lattice of `grid.json`, with its CRS.
pub fn project_grid_of(grid: &GridFile) -> Result<(ProjectGrid, Crs), String> {
    let dem = Lattice::new(
        grid.origin[0],
        grid.origin[1],
        grid.dem_cell,
        grid.size[0],
        grid.size[1],
    )
    .map_err(|e| e.to_string())?;
    let crs: Crs = grid.crs.parse()?;
    Ok((
        ProjectGrid {
            dem,
            ortho_factor: grid.ortho_factor.max(1),
        },
        crs,
    ))
}

/// GeoTIFF georeferencing of a lattice.
pub fn georeference(lattice: &Lattice, crs: Crs, nodata: Option<f64>) -> GeoReference {
    GeoReference {
        transform: GeoTransform {
            origin_x: lattice.west(),
            origin_y: lattice.north(),
            pixel_width: lattice.cell_width(),
            pixel_height: -lattice.cell_height(),
        },
        crs,
        nodata,
        pixel_is_point: false,
    }
}

/// Whether a GeoTIFF's grid is exactly `lattice` (to a millionth of a cell).
pub fn on_lattice(georef: &GeoReference, width: usize, height: usize, lattice: &Lattice) -> bool {
    let t = &georef.transform;
    let tol = 1e-6 * lattice.cell();
    width == lattice.width()
        && height == lattice.height()
        && (t.origin_x - lattice.west()).abs() < tol
        && (t.origin_y - lattice.north()).abs() < tol
        && (t.pixel_width - lattice.cell_width()).abs() < tol
        && (t.pixel_height + lattice.cell_height()).abs() < tol
}

/// Runs the dem stage; returns (and writes) `out/raster.json`.
pub fn dem_stage(project: &Project) -> Result<RasterReport, ProjectError> {
    let layout = project.layout();
    let grid_file = ensure_grid(project)?;
    let bar = crate::progress::progress_bar(
        project.progress,
        "dem",
        "",
        project.epochs.len() as u64,
        "epochs",
    );
    for epoch in &project.epochs {
        bar.inc(1);
        dem_epoch(project, &grid_file, &epoch.name)?;
    }
    bar.finish_and_clear();
    let report = raster_report_from_records(project);
    write_json(&layout.raster_report(), &report)?;
    Ok(report)
}

/// The dem stage's first step (`dem-grid`): the project's lattice. The files it owns.
pub(super) fn grid_unit(project: &Project) -> Result<Vec<PathBuf>, ProjectError> {
    ensure_grid(project)?;
    Ok(vec![project.layout().grid_json()])
}

/// A unit of the `dem` step: the DEMs of the epochs of `part` on the lattice `dem-grid` made.
/// The files it owns.
pub(super) fn unit(project: &Project, part: super::Part) -> Result<Vec<PathBuf>, ProjectError> {
    let layout = project.layout();
    let grid_file = read_json::<GridFile>(&layout.grid_json()).map_err(|e| {
        stage_error(
            "dem",
            format!("{e} (the dem-grid step writes it: run it first)"),
        )
    })?;
    let mut owned = Vec::new();
    for epoch in &project.epochs[part.range(project.epochs.len())] {
        let name = &epoch.name;
        dem_epoch(project, &grid_file, name)?;
        owned.extend(dem_outputs(project, name));
        owned.extend([
            layout.dem_preview(name),
            layout.raster_settings(name, "dem"),
        ]);
    }
    Ok(owned)
}

/// What `work/raster/<epoch>.dem.json` records: what the DEM was made from, and its figures for
/// `out/raster.json`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
struct DemRecord {
    made_from: serde_json::Value,
    cloud_points: usize,
    dem_cells: usize,
    dem_cells_filled: usize,
    dem_seconds: f64,
}

/// What `work/raster/<epoch>.ortho.json` records: what the ortho was made from, and its figures
/// for `out/raster.json`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub(super) struct OrthoRecord {
    pub(super) made_from: serde_json::Value,
    pub(super) ortho_painted_fraction: f64,
    pub(super) seam_jump: f64,
    pub(super) interior_jump: f64,
    pub(super) ortho_seconds: f64,
}

/// `out/raster.json` from every epoch's DEM and ortho records.
pub(super) fn raster_report_from_records(project: &Project) -> RasterReport {
    let layout = project.layout();
    let mut report = RasterReport::default();
    for epoch in &project.epochs {
        let name = &epoch.name;
        let dem = read_sealed_json::<DemRecord>(&layout.raster_settings(name, "dem")).ok();
        let ortho = read_sealed_json::<OrthoRecord>(&layout.raster_settings(name, "ortho")).ok();
        if dem.is_none() && ortho.is_none() {
            continue;
        }
        let entry = report.epochs.entry(name.clone()).or_default();
        if let Some(d) = dem {
            entry.cloud_points = d.cloud_points;
            entry.dem_cells = d.dem_cells;
            entry.dem_cells_filled = d.dem_cells_filled;
            entry.dem_seconds = d.dem_seconds;
        }
        if let Some(o) = ortho {
            entry.ortho_painted_fraction = Some(o.ortho_painted_fraction);
            entry.seam_jump = Some(o.seam_jump);
            entry.interior_jump = Some(o.interior_jump);
            entry.ortho_seconds = Some(o.ortho_seconds);
        }
    }
    report
}

fn dem_outputs(project: &Project, name: &str) -> [PathBuf; 4] {
    let layout = project.layout();
    [
        layout.dem(name),
        layout.dem_count(name),
        layout.dem_std(name),
        layout.dem_filled(name),
    ]
}

/// One epoch's DEM gridded from its cloud unless what it was made from is unchanged; whether it
/// was computed.
fn dem_epoch(project: &Project, grid_file: &GridFile, name: &str) -> Result<bool, ProjectError> {
    let layout = project.layout();
    let (grid, crs) = project_grid_of(grid_file).map_err(|e| ProjectError::Path {
        path: layout.grid_json(),
        message: e,
    })?;
    let cloud_path = layout.dense_cloud(name);
    let options = project.config.raster.dem_options(grid.dem.cell());
    let settings = serde_json::json!({
        "algorithm": DEM_ALGORITHM,
        "grid": [grid_file.origin, [grid_file.dem_cell, 0.0], [grid_file.size[0] as f64, grid_file.size[1] as f64]],
        "options": format!("{options:?}"),
        "cloud": file_stamp(&cloud_path),
    });
    let record_path = layout.raster_settings(name, "dem");
    let outputs = dem_outputs(project, name);
    if read_sealed_json::<DemRecord>(&record_path).is_ok_and(|r| r.made_from == settings)
        && outputs.iter().all(|p| p.is_file())
    {
        tracing::info!(epoch = %name, "DEM up to date");
        return Ok(false);
    }
    let start = Instant::now();
    let cloud = read_las_positions(&cloud_path)?;
    let dem = grid_cloud(&cloud.positions, &grid.dem, &options)
        .map_err(|e| stage_error("dem", format!("epoch \"{name}\": {e}")))?;
    write_dem_files(&dem, crs, &outputs, &layout.dem_preview(name))?;
    let record = DemRecord {
        made_from: settings,
        cloud_points: cloud.positions.len(),
        dem_cells: dem.valid_cells(),
        dem_cells_filled: dem.filled.iter().filter(|f| **f).count(),
        dem_seconds: start.elapsed().as_secs_f64(),
    };
    tracing::info!(
        epoch = %name,
        cells = record.dem_cells,
        filled = record.dem_cells_filled,
        seconds = record.dem_seconds,
        "DEM"
    );
    write_sealed_json(&record_path, &record)?;
    Ok(true)
}

/// Writes the DEM, its count, spread and filled-cell rasters, and the hillshade preview.
pub fn write_dem_files(
    dem: &timesift_raster::Dem,
    crs: Crs,
    [dem_path, count_path, std_path, filled_path]: &[PathBuf; 4],
    preview: &Path,
) -> Result<(), ProjectError> {
    let l = &dem.lattice;
    let nodata = Some(DEM_NODATA as f64);
    let raster = |data: Vec<f32>, nodata: Option<f64>| GeoRaster {
        width: l.width(),
        height: l.height(),
        bands: 1,
        data,
        georef: georeference(l, crs, nodata),
    };
    // A band and its QGIS style beside it (what the report's project draws it with), fitted
    // to the values as written.
    let styled = |path: &Path, data: Vec<f32>, nodata: Option<f64>, style: StyleOf| {
        let style = style(&data, nodata);
        write_f32(path, &raster(data, nodata))?;
        timesift_io::qgis::write_qml(path, &style)?;
        Ok::<(), ProjectError>(())
    };
    // Five independent files, each compressed as it is written: written side by side.
    let writers: [&(dyn Fn() -> Result<(), ProjectError> + Sync); 5] = [
        &|| {
            let heights = dem.height.iter().map(|h| finite_or_nodata(*h)).collect();
            styled(dem_path, heights, nodata, product_styles::dem)
        },
        &|| {
            let counts = dem.count.iter().map(|n| *n as f32).collect();
            styled(count_path, counts, None, product_styles::amount)
        },
        &|| {
            let spread = dem.spread.iter().map(|s| finite_or_nodata(*s)).collect();
            styled(std_path, spread, nodata, product_styles::amount)
        },
        &|| {
            let filled = GeoRaster {
                width: l.width(),
                height: l.height(),
                bands: 1,
                data: dem.filled.iter().map(|f| *f as u8).collect(),
                georef: georeference(l, crs, None),
            };
            write_u8(filled_path, &filled)?;
            timesift_io::qgis::write_qml(filled_path, &product_styles::filled())?;
            Ok(())
        },
        &|| {
            let shade = timesift_raster::hillshade(&dem.height, l);
            let (w, h, small) = timesift_raster::downscale(&shade, 2, l.width(), l.height(), 1024);
            Ok(timesift_io::image::write_png(
                preview, w as u32, h as u32, 2, &small,
            )?)
        },
    ];
    writers.par_iter().try_for_each(|write| write())
}

/// How a band's style is fitted to its values.
type StyleOf = fn(&[f32], Option<f64>) -> timesift_io::qgis::RasterStyle;

/// A height or spread as written: NaN (no points) becomes the DEM's nodata value.
fn finite_or_nodata(value: f32) -> f32 {
    if value.is_finite() { value } else { DEM_NODATA }
}

/// `out/grid.json`, made now unless one made from the same keys and epochs is there.
fn ensure_grid(project: &Project) -> Result<GridFile, ProjectError> {
    let layout = project.layout();
    let raster = &project.config.raster;
    let epochs: Vec<&str> = project.epochs.iter().map(|e| e.name.as_str()).collect();
    let made_from = serde_json::json!({
        "dem_cell": toml::Value::from(raster.dem_cell).to_string(),
        "ortho_cell": toml::Value::from(raster.ortho_cell).to_string(),
        "extent": toml::Value::from(raster.extent).to_string(),
        "epochs": epochs,
    });
    if let Ok(existing) = read_json::<GridFile>(&layout.grid_json())
        && existing.made_from == made_from
    {
        return Ok(existing);
    }
    let cameras = timesift_io::cameras_json::read_cameras_json(&layout.cameras_json())?;
    let inputs = dense_inputs(project)?;
    let mut footprints = Vec::with_capacity(project.epochs.len());
    let mut epoch_gsd = std::collections::BTreeMap::new();
    for (epoch, (_, input)) in project.epochs.iter().zip(&inputs) {
        let cloud = read_las_positions(&layout.dense_cloud(&epoch.name))?;
        let bounds = footprint(&cloud.positions).ok_or_else(|| {
            stage_error(
                "dem",
                format!(
                    "epoch \"{}\": {} has too few points for a footprint (run the dense stage)",
                    epoch.name,
                    layout.dense_cloud(&epoch.name).display()
                ),
            )
        })?;
        let gsd = epoch_ground_sample_distance(input, &epoch.name)?;
        epoch_gsd.insert(epoch.name.clone(), gsd);
        footprints.push(EpochFootprint { bounds, gsd });
    }
    let options = raster.grid_options().map_err(|e| {
        ProjectError::config(
            project.layout().project_toml(),
            "raster.extent",
            e.to_string(),
        )
    })?;
    let grid = plan_grid(&footprints, &options)
        .map_err(|e| stage_error("dem", format!("{e}{}", scale_hint(&epoch_gsd))))?;
    let ortho = grid.ortho();
    let file = GridFile {
        crs: cameras.crs.clone(),
        origin: [grid.dem.west(), grid.dem.north()],
        dem_cell: grid.dem.cell(),
        ortho_cell: ortho.cell(),
        ortho_factor: grid.ortho_factor,
        size: [grid.dem.width(), grid.dem.height()],
        ortho_size: [ortho.width(), ortho.height()],
        epoch_gsd,
        made_from,
    };
    write_json(&layout.grid_json(), &file)?;
    tracing::info!(
        cell = file.dem_cell,
        width = file.size[0],
        height = file.size[1],
        "project lattice"
    );
    Ok(file)
}

/// The x and y extent of a cloud without its outermost points on each side.
fn footprint(points: &[[f64; 3]]) -> Option<Bounds> {
    if points.len() < 3 {
        return None;
    }
    let trim = (points.len() as f64 * FOOTPRINT_TRIM) as usize;
    let range = |axis: usize| {
        let mut v: Vec<f64> = points.iter().map(|p| p[axis]).collect();
        let (_, lo, _) = v.select_nth_unstable_by(trim, f64::total_cmp);
        let lo = *lo;
        let hi_index = v.len() - 1 - trim;
        let (_, hi, _) = v.select_nth_unstable_by(hi_index, f64::total_cmp);
        (lo, *hi)
    };
    let (x0, x1) = range(0);
    let (y0, y1) = range(1);
    Bounds::new(x0, y0, x1, y1).ok()
}

fn focal_px(camera: &Camera) -> f64 {
    match camera {
        Camera::Brown(c) => c.f,
        Camera::Pinhole(c) => c.f,
    }
}

/// Median over the epoch's oriented images of the median depth of the sparse points each
/// sees, divided by its focal length: the ground sample distance of the original images.
pub fn epoch_ground_sample_distance(input: &EpochInput, name: &str) -> Result<f64, ProjectError> {
    let mut depths: Vec<Vec<f64>> = vec![Vec::new(); input.views.len()];
    for p in &input.points {
        for &v in &p.views {
            let z = input.views[v].cam_from_world.transform_point(&p.position).z;
            if z > 0.0 {
                depths[v].push(z);
            }
        }
    }
    let mut gsd: Vec<f64> = depths
        .iter_mut()
        .zip(&input.views)
        .filter(|(d, _)| !d.is_empty())
        .map(|(d, v)| median(d) / focal_px(&v.camera))
        .filter(|g| g.is_finite() && *g > 0.0)
        .collect();
    if gsd.is_empty() {
        return Err(stage_error(
            "dem",
            format!(
                "epoch \"{name}\": no oriented image sees a sparse point (run the align stage)"
            ),
        ));
    }
    Ok(median(&mut gsd))
}

fn median(v: &mut [f64]) -> f64 {
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    *m
}

/// Ratio of the epochs' ground sampling distances beyond which they cannot share one datum.
const GSD_RATIO_UNSCALED: f64 = 100.0;

/// When the epochs' ground sampling distances differ by orders of magnitude, the words that
/// name the likely cause: some epoch was oriented without a datum (no GNSS and no control in it,
/// e.g. `independent` with control points in the reference epoch only), so its cloud is in an
/// arbitrary scale and no grid can hold all epochs. Empty otherwise.
fn scale_hint(epoch_gsd: &std::collections::BTreeMap<String, f64>) -> String {
    let (Some(lo), Some(hi)) = (
        epoch_gsd.values().copied().reduce(f64::min),
        epoch_gsd.values().copied().reduce(f64::max),
    ) else {
        return String::new();
    };
    if !(hi > GSD_RATIO_UNSCALED * lo) {
        return String::new();
    }
    let list: Vec<String> = epoch_gsd
        .iter()
        .map(|(e, g)| format!("{e} {g:.3e} m"))
        .collect();
    format!(
        "; the epochs' ground sampling distances differ by a factor of {:.0} ({}): an epoch \
         without GNSS or control points of its own has no scale when oriented alone (`align.method` \
         \"independent\"); give it control points (`align.gcps_in_all_epochs`) or choose a \
         strategy that ties it to the reference epoch",
        hi / lo,
        list.join(", ")
    )
}

#[cfg(test)]
mod scale_hint_tests {
    use super::*;

    #[test]
    fn epochs_of_very_different_scale_are_named_and_similar_ones_are_not() {
        let gsd = |values: &[(&str, f64)]| {
            values
                .iter()
                .map(|(e, g)| (e.to_string(), *g))
                .collect::<std::collections::BTreeMap<_, _>>()
        };
        assert_eq!(scale_hint(&gsd(&[("a", 0.40), ("b", 0.45)])), "");
        assert_eq!(scale_hint(&gsd(&[])), "");
        let hint = scale_hint(&gsd(&[("1971", 2.7), ("1981", 0.0046)]));
        assert!(
            hint.contains("1971") && hint.contains("1981") && hint.contains("independent"),
            "{hint}"
        );
    }
}
