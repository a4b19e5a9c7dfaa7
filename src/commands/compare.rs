//! `timesift compare` and the `change` stage: DEM of difference (optionally co-registered), stable-
//! area statistics, level of detection, volumes and maps for two DEMs; ICP and M3C2 for two point
//! clouds. Files in, files out; the computations are in `timesift-change`.

use std::path::{Path, PathBuf};

use serde::Serialize;
use timesift_change::ChangeError;
use timesift_change::checkpoints::{CheckPointReport, dem_residuals};
use timesift_change::correlation::Variogram;
use timesift_change::grid::{Dem, Grid, check_same_crs};
use timesift_change::icp::{IcpModel, IcpOptions, IcpResult, icp, select};
use timesift_change::m3c2::{M3c2Params, M3c2Point, m3c2, subsample_core_points};
use timesift_change::maps::{MapOptions, difference_map, histogram};
use timesift_change::mask::Mask;
use timesift_change::nuth_kaab::{NuthKaabOptions, NuthKaabResult};
use timesift_change::pair::{PairAnalysis, PairOptions, analyse_pair};
use timesift_change::stats::{Statistics, statistics};
use timesift_change::trend::PlaneTrend;
use timesift_change::volume::Volumes;
use timesift_io::IoError;
use timesift_io::coords::Crs;
use timesift_io::geotiff::{read_f32, write_f32};
use timesift_io::pointcloud::{
    AttributeValues, ExtraAttribute, LasWriteOptions, PointCloud, read_las, write_las,
};
use timesift_io::qgis::write_qml;

use crate::stages::product_styles;
use timesift_io::wkt::Polygon;

use crate::ProjectError;
use crate::config::Coregistration;
use crate::report::write_json;

/// Options of a DEM comparison.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DemCompareOptions {
    /// A value to treat as nodata in both DEMs besides their declared nodata (e.g. −10000).
    pub extra_nodata: Option<f64>,
    /// Stable areas: a CSV/WKT file of polygons or a mask GeoTIFF (non-zero = stable).
    pub stable: Option<PathBuf>,
    /// Co-registration of the second DEM onto the first.
    pub coregistration: Coregistration,
    /// σ of each DEM (m), for the LoD; default: from the stable-area NMAD of the difference.
    pub sigmas: Option<(f64, f64)>,
    /// Region for the volumes (polygons file or mask GeoTIFF); default: every cell.
    pub region: Option<PathBuf>,
    /// Check points (name, E, N, H): DEM height residuals are reported for both DEMs.
    pub checkpoints: Vec<(String, [f64; 3])>,
}

/// Options of a point-cloud comparison.
#[derive(Debug, Clone, PartialEq)]
pub struct CloudCompareOptions {
    /// Stable-area polygons (CSV/WKT), used by ICP.
    pub stable: Option<PathBuf>,
    /// Register the second cloud onto the first by ICP (on stable points) before M3C2.
    pub icp: Option<IcpModel>,
    /// M3C2 parameters; a registration error of `None` takes the ICP RMS (or 0).
    pub m3c2: M3c2Params,
    /// Registration error given by the user.
    pub registration_error: Option<f64>,
    /// Core-point spacing, m.
    pub core_spacing: f64,
}

/// What a DEM comparison found; written as `stats.json`.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct DemReport {
    /// The first (earlier) DEM.
    pub a: String,
    /// The second (later) DEM.
    pub b: String,
    /// CRS of both.
    pub crs: String,
    /// Co-registration applied to `b`.
    pub coregistration: Option<NuthKaabResult>,
    /// Statistics of the difference over every cell.
    pub all: Statistics,
    /// Statistics over the stable areas.
    pub stable: Option<Statistics>,
    /// Least-squares plane of the difference over the stable areas: a tilt between the DEMs
    /// that the stable median cannot show.
    #[serde(default)]
    pub stable_trend: Option<PlaneTrend>,
    /// Variogram of the difference over the stable areas (spherical model and its lags): how far
    /// the DEMs' errors correlate, which the volumes' random σ follows.
    #[serde(default)]
    pub stable_variogram: Option<Variogram>,
    /// 95 % level of detection, m.
    pub lod95: Option<f64>,
    /// Where the LoD came from.
    pub lod_source: String,
    /// Cells with |dz| > LoD95 among valid cells.
    pub significant_cells: Option<usize>,
    /// Volumes over the region, every cell counted.
    pub volumes: Volumes,
    /// Volumes counting only cells beyond the LoD.
    pub volumes_beyond_lod: Option<Volumes>,
    /// DEM height minus check-point height, for the first DEM and the (co-registered) second.
    pub checkpoints: Option<[CheckPointReport; 2]>,
    /// Things the user should know (e.g. a co-registration that did not lower the stable NMAD).
    pub warnings: Vec<String>,
    /// Files written.
    pub outputs: Vec<String>,
}

/// What a cloud comparison found; written as `stats.json`.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct CloudReport {
    /// The first cloud.
    pub a: String,
    /// The second cloud.
    pub b: String,
    /// ICP result (second cloud onto the first), when run.
    pub icp: Option<IcpResult>,
    /// Core points.
    pub core_points: usize,
    /// Core points with a distance.
    pub defined: usize,
    /// Core points with significant change.
    pub significant: usize,
    /// Statistics of the M3C2 distances.
    pub distance: Option<Statistics>,
    /// Statistics of the LoD95.
    pub lod95: Option<Statistics>,
    /// Registration error used in the LoD, m.
    pub registration_error: f64,
    /// Files written.
    pub outputs: Vec<String>,
}

fn change_err(context: impl Into<String>) -> impl FnOnce(ChangeError) -> ProjectError {
    let context = context.into();
    move |source| ProjectError::Change { context, source }
}

fn load_dem(path: &Path, extra_nodata: Option<f64>) -> Result<Dem, ProjectError> {
    let raster = read_f32(path)?;
    Dem::from_raster(raster, extra_nodata).map_err(change_err(path.display().to_string()))
}

/// What `timesift compare` prints for two clouds, a line per result, then the files written.
impl std::fmt::Display for CloudReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if let Some(icp) = &self.icp {
            writeln!(
                f,
                "ICP: rotation {:.4}°, translation {:.3?} m, scale {:.6}, RMS {:.4} m over {} pairs",
                icp.rotation_deg, icp.translation, icp.scale, icp.rms, icp.pairs
            )?;
        }
        writeln!(
            f,
            "M3C2: {} core points, {} with a distance, {} significant",
            self.core_points, self.defined, self.significant
        )?;
        if let Some(d) = &self.distance {
            writeln!(
                f,
                "distance: median {:.4} m, mean {:.4} m, NMAD {:.4} m",
                d.median, d.mean, d.nmad
            )?;
        }
        for file in &self.outputs {
            writeln!(f, "wrote {file}")?;
        }
        Ok(())
    }
}

/// What `timesift compare` prints for two DEMs (warnings apart: they go to standard error), a
/// line per result, then the files written.
impl std::fmt::Display for DemReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if let Some(c) = &self.coregistration {
            writeln!(
                f,
                "co-registration: shift east {:.3} m, north {:.3} m ({:.3}, {:.3} px), vertical {:.3} m; stable NMAD {:.4} → {:.4} m",
                c.shift_east_m,
                c.shift_north_m,
                c.shift_px[0],
                c.shift_px[1],
                c.shift_z,
                c.nmad_before,
                c.nmad_after
            )?;
        }
        let s = &self.all;
        writeln!(
            f,
            "DoD (b − a): {} cells, mean {:.4} m, median {:.4} m, std {:.4} m, NMAD {:.4} m",
            s.count, s.mean, s.median, s.std, s.nmad
        )?;
        if let Some(s) = &self.stable {
            writeln!(
                f,
                "stable: {} cells, mean {:.4} m, median {:.4} m, std {:.4} m, RMSE {:.4} m, NMAD {:.4} m",
                s.count, s.mean, s.median, s.std, s.rmse, s.nmad
            )?;
        }
        if let Some(t) = &self.stable_trend {
            writeln!(
                f,
                "stable plane: {:.2} mm/m towards {:.0}°, {:.4} m across {:.0} m",
                t.slope * 1000.0,
                t.azimuth_deg,
                t.gain_m,
                t.extent_m
            )?;
        }
        if let Some(l) = self.lod95 {
            writeln!(f, "LoD95 {l:.4} m ({})", self.lod_source)?;
        }
        self.fmt_checkpoints(f)?;
        self.fmt_volumes(f)?;
        for file in &self.outputs {
            writeln!(f, "wrote {file}")?;
        }
        Ok(())
    }
}

impl DemReport {
    /// The check points' height errors on each DEM.
    fn fmt_checkpoints(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let Some(reports) = &self.checkpoints else {
            return Ok(());
        };
        for (label, c) in ["a", "b"].iter().zip(reports) {
            if let Some(h) = &c.height {
                writeln!(
                    f,
                    "check points on {label}: {} (missing {}), dH mean {:.4} m, RMSE {:.4} m, NMAD {:.4} m",
                    h.count,
                    c.missing.len(),
                    h.mean,
                    h.rmse,
                    h.nmad
                )?;
            }
        }
        Ok(())
    }

    /// The volumes, with their uncertainty when the LoD is known, and beyond the LoD.
    fn fmt_volumes(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let v = &self.volumes;
        let uncertainty = if self.lod95.is_some() {
            format!(" ± {:.2}", v.sigma_net)
        } else {
            " (uncertainty unknown: give --stable or --sigma)".to_string()
        };
        writeln!(
            f,
            "volumes: cut {:.2} m³, fill {:.2} m³, net {:.2}{uncertainty} m³ over {:.1} m²",
            v.cut, v.fill, v.net, v.area
        )?;
        if let Some(v) = &self.volumes_beyond_lod {
            writeln!(
                f,
                "beyond LoD: cut {:.2} m³, fill {:.2} m³, net {:.2} ± {:.2} m³",
                v.cut, v.fill, v.net, v.sigma_net
            )?;
        }
        Ok(())
    }
}

/// Polygons of a stable-area or region file: `stable.csv` lines (`[name,]WKT`) or bare WKT.
pub fn read_polygons(path: &Path) -> Result<Vec<Polygon>, ProjectError> {
    let areas = timesift_io::csv_inputs::read_stable_areas(path)?;
    let polygons: Vec<Polygon> = areas.into_iter().flat_map(|a| a.polygons).collect();
    if polygons.is_empty() {
        return Err(ProjectError::Path {
            path: path.to_path_buf(),
            message: "holds no polygon; expected lines of [name,]POLYGON(...) or MULTIPOLYGON(...)"
                .into(),
        });
    }
    Ok(polygons)
}

/// A mask on `grid` from a polygons file or a mask GeoTIFF.
/// Whether a stable-area or region file is a mask GeoTIFF (by its extension) rather than
/// polygons.
fn is_tiff(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("tif") || e.eq_ignore_ascii_case("tiff"))
}

fn load_mask(path: &Path, grid: Grid) -> Result<Mask, ProjectError> {
    let mask = if is_tiff(path) {
        let raster = load_dem(path, None)?;
        Mask::from_raster(grid, &raster).map_err(change_err(path.display().to_string()))?
    } else {
        Mask::from_polygons(grid, &read_polygons(path)?)
    };
    if mask.count() == 0 {
        return Err(ProjectError::Change {
            context: path.display().to_string(),
            source: ChangeError::EmptyStable("it selects no cell of the DEM's grid".into()),
        });
    }
    Ok(mask)
}

fn write_png(path: &Path, img: &image::RgbImage) -> Result<(), ProjectError> {
    timesift_io::image::write_png(path, img.width(), img.height(), 3, img.as_raw())?;
    Ok(())
}

fn create_dir(out: &Path) -> Result<(), ProjectError> {
    std::fs::create_dir_all(out).map_err(|e| IoError::io(out, e).into())
}

/// Check points of a CSV file (`name,x,y,z`) as (name, position).
pub fn read_checkpoints(path: &Path) -> Result<Vec<(String, [f64; 3])>, ProjectError> {
    Ok(named_positions(&timesift_io::csv_inputs::read_checkpoints(
        path,
    )?))
}

/// Control or check points as (name, position).
pub(crate) fn named_positions(
    points: &[timesift_io::csv_inputs::ControlPoint],
) -> Vec<(String, [f64; 3])> {
    points
        .iter()
        .map(|c| (c.name.clone(), [c.position.x, c.position.y, c.position.z]))
        .collect()
}

/// Compares two DEMs and writes `dod.tif`, `stats.json`, `dod.png`, `histogram.png`,
/// `significant.tif` (1 where |dz| > LoD95, when there is a LoD) and `coregistered.tif` (when
/// co-registering) into `out`.
pub fn compare_dems(
    a: &Path,
    b: &Path,
    out: &Path,
    options: &DemCompareOptions,
) -> Result<DemReport, ProjectError> {
    let dem_a = load_dem(a, options.extra_nodata)?;
    let dem_b = load_dem(b, options.extra_nodata)?;
    let pair = format!("{} and {}", a.display(), b.display());
    check_same_crs(dem_a.grid.crs, dem_b.grid.crs).map_err(change_err(pair.clone()))?;
    let stable = match &options.stable {
        Some(path) => Some(load_mask(path, dem_a.grid)?),
        None => None,
    };
    let region = match &options.region {
        Some(path) => Some(load_mask(path, dem_a.grid)?),
        None => None,
    };
    let pair_options = PairOptions {
        coregistration: match options.coregistration {
            Coregistration::None => None,
            mode => Some(NuthKaabOptions {
                horizontal: mode == Coregistration::NuthKaab,
                ..Default::default()
            }),
        },
        sigmas: options.sigmas,
    };
    let analysis = analyse_pair(
        &dem_a,
        &dem_b,
        stable.as_ref(),
        region.as_ref(),
        &pair_options,
    )
    .map_err(change_err(pair.clone()))?;
    create_dir(out)?;
    let mut outputs = write_dod_rasters(out, &analysis)?;
    let dod = &analysis.dod;
    let lod = analysis.lod95;
    let name = |p: &Path| {
        p.file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default()
    };
    let title = format!("{} - {}", name(b), name(a));
    outputs.extend(write_dod_figures(out, dod, lod, title)?);
    let stats_path = out.join("stats.json");
    outputs.push(stats_path.display().to_string());
    let report = DemReport {
        a: a.display().to_string(),
        b: b.display().to_string(),
        crs: dod.grid.crs.to_string(),
        checkpoints: (!options.checkpoints.is_empty()).then(|| {
            [
                dem_residuals(&dem_a, &options.checkpoints),
                dem_residuals(&analysis.later, &options.checkpoints),
            ]
        }),
        coregistration: analysis.coregistration,
        all: analysis.all,
        stable: analysis.stable,
        stable_trend: analysis.stable_trend,
        stable_variogram: analysis.stable_variogram,
        lod95: lod,
        lod_source: analysis.lod_source.to_string(),
        significant_cells: analysis.significant_cells,
        volumes: analysis.volumes,
        volumes_beyond_lod: analysis.volumes_beyond_lod,
        warnings: analysis.warnings,
        outputs,
    };
    write_json(&stats_path, &report)?;
    Ok(report)
}

/// The co-registered later DEM (when co-registered), the DoD, and where the DoD is beyond the
/// LoD (1 significant, 0 not, nodata where the DoD has none); the paths written.
fn write_dod_rasters(out: &Path, analysis: &PairAnalysis) -> Result<Vec<String>, ProjectError> {
    let mut outputs = Vec::new();
    if analysis.coregistration.is_some() {
        let path = out.join("coregistered.tif");
        write_f32(&path, &analysis.later.to_raster())?;
        outputs.push(path.display().to_string());
    }
    let dod = &analysis.dod;
    let dod_path = out.join("dod.tif");
    write_f32(&dod_path, &dod.to_raster())?;
    outputs.push(dod_path.display().to_string());
    // QGIS's style beside it: change about zero, the LoD95 band not drawn.
    let style = product_styles::dod(&dod.values, None, analysis.lod95);
    outputs.push(write_qml(&dod_path, &style)?.display().to_string());
    if let Some(flags) = analysis.significance() {
        let mask = Dem {
            grid: dod.grid,
            values: flags
                .iter()
                .map(|&f| if f == 255 { f32::NAN } else { f as f32 })
                .collect(),
        };
        let path = out.join("significant.tif");
        write_f32(&path, &mask.to_raster())?;
        outputs.push(path.display().to_string());
        let style = write_qml(&path, &product_styles::significant())?;
        outputs.push(style.display().to_string());
    }
    Ok(outputs)
}

/// The DoD's map (the LoD band grey) and histogram as PNG files; the paths written.
fn write_dod_figures(
    out: &Path,
    dod: &Dem,
    lod: Option<f64>,
    title: String,
) -> Result<Vec<String>, ProjectError> {
    let map = difference_map(
        dod,
        &MapOptions {
            title: title.clone(),
            lod,
            ..Default::default()
        },
    );
    let map_path = out.join("dod.png");
    write_png(&map_path, &map)?;
    let hist_values: Vec<f64> = dod.values.iter().map(|&v| v as f64).collect();
    let hist = histogram(&hist_values, &title, "m", None, lod);
    let hist_path = out.join("histogram.png");
    write_png(&hist_path, &hist)?;
    Ok(vec![
        map_path.display().to_string(),
        hist_path.display().to_string(),
    ])
}

/// Compares two point clouds (LAS/LAZ): optional ICP of `b` onto `a`, then M3C2 from `a` to `b`;
/// writes `m3c2.laz` (core points with distance, lod95, significant, counts), `m3c2_stats.json`,
/// `m3c2.png` (distances gridded at the core spacing) and `m3c2_histogram.png`.
pub fn compare_clouds(
    a: &Path,
    b: &Path,
    out: &Path,
    options: &CloudCompareOptions,
) -> Result<CloudReport, ProjectError> {
    let cloud_a = read_las(a)?;
    let cloud_b = read_las(b)?;
    let pair = format!("{} and {}", a.display(), b.display());
    check_same_crs(cloud_a.crs, cloud_b.crs).map_err(change_err(pair.clone()))?;
    let mut positions_b = cloud_b.positions.clone();
    let icp_result = match options.icp {
        Some(model) => {
            // Only ICP selects points by the stable areas.
            let stable = match &options.stable {
                Some(path) => Some(StableAreas::read(path)?),
                None => None,
            };
            let r = icp_on_stable(
                &cloud_a.positions,
                &positions_b,
                stable.as_ref(),
                model,
                &pair,
            )?;
            for p in &mut positions_b {
                *p = r.transform(p);
            }
            Some(r)
        }
        None => None,
    };
    let registration_error = options
        .registration_error
        .or(icp_result.as_ref().map(|r| r.rms))
        .unwrap_or(0.0);
    let params = M3c2Params {
        registration_error,
        ..options.m3c2.clone()
    };
    let core = subsample_core_points(&cloud_a.positions, options.core_spacing)
        .map_err(change_err("core points"))?;
    let results = m3c2(&cloud_a.positions, &positions_b, &core, &params)
        .map_err(change_err(format!("M3C2 of {pair}")))?;
    create_dir(out)?;
    let mut outputs = Vec::new();
    let laz = out.join("m3c2.laz");
    write_las(
        &laz,
        &m3c2_cloud(&core, &results, cloud_a.crs),
        &LasWriteOptions::default(),
    )?;
    outputs.push(laz.display().to_string());

    let distances: Vec<f64> = results.iter().map(|r| r.distance).collect();
    let lods: Vec<f64> = results.iter().map(|r| r.lod95).collect();
    let title = "M3C2 distance";
    let median_lod = statistics(lods.iter().copied()).map(|s| s.median);
    let hist_path = out.join("m3c2_histogram.png");
    write_png(
        &hist_path,
        &histogram(&distances, title, "m", None, median_lod),
    )?;
    outputs.push(hist_path.display().to_string());
    if let Some(grid_dem) =
        Dem::mean_of_points(&core, &distances, options.core_spacing, cloud_a.crs)
    {
        let map_path = out.join("m3c2.png");
        let map = difference_map(
            &grid_dem,
            &MapOptions {
                title: title.into(),
                ..Default::default()
            },
        );
        write_png(&map_path, &map)?;
        outputs.push(map_path.display().to_string());
    }
    let stats_path = out.join("m3c2_stats.json");
    outputs.push(stats_path.display().to_string());
    let report = CloudReport {
        a: a.display().to_string(),
        b: b.display().to_string(),
        icp: icp_result,
        core_points: core.len(),
        defined: distances.iter().filter(|d| d.is_finite()).count(),
        significant: results.iter().filter(|r| r.significant()).count(),
        distance: statistics(distances.iter().copied()),
        lod95: statistics(lods.iter().copied()),
        registration_error,
        outputs,
    };
    write_json(&stats_path, &report)?;
    Ok(report)
}

/// Stable areas as points are judged against them: polygons, or a mask GeoTIFF (non-zero,
/// finite = stable) such as the align stage's `out/stable_found.tif`.
enum StableAreas {
    Polygons(Vec<Polygon>),
    Mask(timesift_io::geotiff::GeoRaster<f32>),
}

impl StableAreas {
    fn read(path: &Path) -> Result<StableAreas, ProjectError> {
        Ok(match is_tiff(path) {
            true => StableAreas::Mask(timesift_io::geotiff::read_f32(path)?),
            false => StableAreas::Polygons(read_polygons(path)?),
        })
    }

    fn contains(&self, x: f64, y: f64) -> bool {
        match self {
            StableAreas::Polygons(polygons) => polygons.iter().any(|p| p.contains(x, y)),
            StableAreas::Mask(mask) => {
                let (col, row) = mask.georef.transform.world_to_pixel(x, y);
                let inside = col >= 0.0
                    && row >= 0.0
                    && (col as usize) < mask.width
                    && (row as usize) < mask.height;
                inside && {
                    let v = mask.data[row as usize * mask.width + col as usize];
                    v.is_finite() && v != 0.0 && mask.georef.nodata != Some(v as f64)
                }
            }
        }
    }
}

/// ICP of cloud `b` onto cloud `a` over their points in the stable areas (every point without
/// them).
fn icp_on_stable(
    a: &[[f64; 3]],
    b: &[[f64; 3]],
    stable: Option<&StableAreas>,
    model: IcpModel,
    pair: &str,
) -> Result<IcpResult, ProjectError> {
    let in_stable = |points: &[[f64; 3]]| -> Vec<bool> {
        match stable {
            Some(areas) => points.iter().map(|p| areas.contains(p[0], p[1])).collect(),
            None => vec![true; points.len()],
        }
    };
    let keep_a = in_stable(a);
    let keep_b = in_stable(b);
    if !keep_a.iter().any(|&k| k) || !keep_b.iter().any(|&k| k) {
        return Err(ProjectError::Change {
            context: pair.to_string(),
            source: ChangeError::EmptyStable("no point lies in the stable areas".into()),
        });
    }
    icp(
        &select(b, &keep_b),
        &select(a, &keep_a),
        &IcpOptions {
            model,
            ..Default::default()
        },
    )
    .map_err(change_err(format!("ICP of {pair}")))
}

/// The M3C2 result as a cloud: core points with distance, lod95, significant, count1, count2.
fn m3c2_cloud(core: &[[f64; 3]], results: &[M3c2Point], crs: Crs) -> PointCloud {
    let f64s =
        |f: &dyn Fn(&M3c2Point) -> f64| AttributeValues::F64(results.iter().map(f).collect());
    PointCloud {
        positions: core.to_vec(),
        colors: None,
        attributes: vec![
            ExtraAttribute {
                name: "distance".into(),
                values: f64s(&|r| r.distance),
            },
            ExtraAttribute {
                name: "lod95".into(),
                values: f64s(&|r| r.lod95),
            },
            ExtraAttribute {
                name: "significant".into(),
                values: AttributeValues::U8(
                    results.iter().map(|r| r.significant() as u8).collect(),
                ),
            },
            ExtraAttribute {
                name: "count1".into(),
                values: AttributeValues::F32(results.iter().map(|r| r.count[0] as f32).collect()),
            },
            ExtraAttribute {
                name: "count2".into(),
                values: AttributeValues::F32(results.iter().map(|r| r.count[1] as f32).collect()),
            },
        ],
        crs,
    }
}
