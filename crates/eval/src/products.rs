//! A project's products against the truth of its synthetic scene: each epoch's DEM against the
//! true surface, the painted targets found in an orthomosaic, and each changed region's volume
//! against the true one (`truth/change.json`).

use std::collections::BTreeMap;
use std::path::Path;

use timesift_change::grid::Dem;
use timesift_change::mask::Mask;
use timesift_change::volume::{VolumeOptions, volumes};
use timesift_io::layout::Layout;

use crate::{EvalError, ProjectTruth};

/// The true surface of `epoch` (`truth/dem_<epoch>.tif`).
pub fn true_dem(layout: &Layout, epoch: &str) -> Result<Dem, EvalError> {
    let path = layout.truth_dir().join(format!("dem_{epoch}.tif"));
    Dem::from_raster(timesift_io::geotiff::read_f32(&path)?, None).map_err(|source| {
        EvalError::Change {
            context: path.display().to_string(),
            source,
        }
    })
}

/// The painted targets of a synthetic project (`truth/points.csv`) located in an RGBA ortho
/// with [`timesift_film::locate_target`]: how many were found and the RMS distance of the found ones from
/// their true positions, in ortho cells. `target_radius` is the targets' radius in metres.
pub fn ortho_target_errors(
    layout: &Layout,
    ortho: &timesift_io::geotiff::GeoRaster<u8>,
    target_radius: f64,
) -> Result<(usize, Option<f64>), EvalError> {
    let points = timesift_io::truth_csv::read_true_points(&layout.truth_dir().join("points.csv"))?;
    let t = ortho.georef.transform;
    let radius = target_radius / t.pixel_width;
    let (mut sq, mut found) = (0.0, 0usize);
    for point in &points {
        let near = t.world_to_pixel(point.position.x, point.position.y);
        let located = timesift_film::locate_target(
            &ortho.data,
            ortho.width,
            ortho.height,
            near,
            radius,
            0.5 * radius,
        );
        if let Some((c, r)) = located {
            sq += (c - near.0).powi(2) + (r - near.1).powi(2);
            found += 1;
        }
    }
    Ok((found, (found > 0).then(|| (sq / found as f64).sqrt())))
}

/// Height errors (DEM − truth, metres) of the measured cells of a DEM (`count` > 0, not
/// nodata) whose centre `keep` accepts, against a truth DEM sampled bilinearly.
pub fn dem_height_errors(
    dem: &timesift_io::geotiff::GeoRaster<f32>,
    count: &timesift_io::geotiff::GeoRaster<f32>,
    truth: &timesift_change::grid::Dem,
    keep: impl Fn(f64, f64) -> bool,
) -> Vec<f64> {
    dem_height_error_points(dem, count, truth, keep)
        .into_iter()
        .map(|(_, _, e)| e)
        .collect()
}

/// [`dem_height_errors`] with each error's cell centre: (x, y, error), for a plane through them.
pub fn dem_height_error_points(
    dem: &timesift_io::geotiff::GeoRaster<f32>,
    count: &timesift_io::geotiff::GeoRaster<f32>,
    truth: &timesift_change::grid::Dem,
    keep: impl Fn(f64, f64) -> bool,
) -> Vec<(f64, f64, f64)> {
    let t = dem.georef.transform;
    let nodata = dem.georef.nodata.map(|v| v as f32);
    let mut err = Vec::new();
    for r in 0..dem.height {
        for c in 0..dem.width {
            let h = dem.get(c, r, 0);
            if Some(h) == nodata || !h.is_finite() || count.get(c, r, 0) == 0.0 {
                continue;
            }
            let (x, y) = t.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
            if !keep(x, y) {
                continue;
            }
            let z = truth.bilinear(x, y);
            if z.is_finite() {
                err.push((x, y, h as f64 - z));
            }
        }
    }
    err
}

/// Reads `truth/change.json`.
fn read_change_truth(path: &Path) -> Result<ChangeTruth, EvalError> {
    let text = timesift_io::fsutil::read_text(path)?;
    serde_json::from_str(&text).map_err(|e| EvalError::Truth {
        path: path.to_path_buf(),
        message: format!("not the expected truth of the changed regions: {e}"),
    })
}

/// `truth/change.json` as `synth` writes it: the regions that changed and their true volumes.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
pub struct ChangeTruth {
    /// Epoch names in order.
    pub epochs: Vec<String>,
    /// Changed regions.
    pub regions: Vec<TrueRegion>,
}

/// One region of [`ChangeTruth`].
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
pub struct TrueRegion {
    /// Region name.
    pub name: String,
    /// What happens there.
    #[serde(default)]
    pub description: String,
    /// Outline in world coordinates (E, N).
    pub polygon_wkt: String,
    /// True volume change between pairs of epochs.
    pub volumes: Vec<TrueVolume>,
}

/// The true volume change of a region between two epochs, m³ (positive: material added).
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
pub struct TrueVolume {
    /// Earlier epoch.
    pub from: String,
    /// Later epoch.
    pub to: String,
    /// Net volume, m³.
    pub volume_m3: f64,
}

/// A region's measured volume change next to the true one.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RegionVolume {
    /// Region name.
    pub region: String,
    /// Earlier epoch.
    pub from: String,
    /// Later epoch.
    pub to: String,
    /// True net volume, m³.
    pub true_m3: f64,
    /// Net volume of the DoD of the two epochs' DEMs inside the region, m³; NaN when no cell of
    /// the region has a height in both DEMs (`coverage` 0).
    pub measured_m3: f64,
    /// Its 1-σ uncertainty (random from the stable-area NMAD correlated as the stable-area
    /// variogram says, systematic from the stable-area median), m³; NaN with the volume.
    pub sigma_m3: f64,
    /// Fraction of the region's cells with a difference.
    pub coverage: f64,
}

/// Every true volume of `truth/change.json` measured on the project's DEMs (the DoD later −
/// earlier inside the region's polygon, with the uncertainty model of the change stage).
pub fn region_volumes(project: &ProjectTruth<'_>) -> Result<Vec<RegionVolume>, EvalError> {
    let layout = &project.layout;
    let truth = read_change_truth(&layout.truth_dir().join("change.json"))?;
    let stable_polygons = &project.stable_polygons;
    let change_err = |context: String| move |source| EvalError::Change { context, source };
    // Each epoch's DEM read once, each pair's DoD and uncertainty made once: the regions share
    // them.
    let mut dems: BTreeMap<String, Dem> = BTreeMap::new();
    let mut dods: BTreeMap<(String, String), (Dem, VolumeOptions)> = BTreeMap::new();
    let mut rows = Vec::new();
    for region in &truth.regions {
        let polygons = timesift_io::wkt::parse_polygons(&region.polygon_wkt).map_err(|e| {
            EvalError::Truth {
                path: layout.truth_dir().join("change.json"),
                message: format!("region {}: {e}", region.name),
            }
        })?;
        for v in &region.volumes {
            let context = format!("region {} from {} to {}", region.name, v.from, v.to);
            let key = (v.from.clone(), v.to.clone());
            if !dods.contains_key(&key) {
                for epoch in [&v.from, &v.to] {
                    if !dems.contains_key(epoch) {
                        let path = layout.dem(epoch);
                        let raster = timesift_io::geotiff::read_f32(&path)?;
                        let dem = Dem::from_raster(raster, None)
                            .map_err(change_err(path.display().to_string()))?;
                        dems.insert(epoch.clone(), dem);
                    }
                }
                let dod = timesift_change::dod::dem_of_difference(&dems[&v.from], &dems[&v.to])
                    .map_err(change_err(context.clone()))?;
                let stable = Mask::from_polygons(dod.grid, stable_polygons);
                let stable_dz = timesift_change::stats::statistics(
                    dod.values
                        .iter()
                        .zip(&stable.cells)
                        .filter(|(_, s)| **s)
                        .map(|(v, _)| *v as f64),
                );
                let stable_variogram =
                    timesift_change::correlation::variogram(&dod, Some(&stable)).ok();
                let options = timesift_change::pair::volume_uncertainty(
                    None,
                    stable_dz.as_ref(),
                    stable_variogram.as_ref(),
                );
                dods.insert(key.clone(), (dod, options));
            }
            let (dod, options) = &dods[&key];
            let mask = Mask::from_polygons(dod.grid, &polygons);
            let inside = mask.count().max(1);
            let measured_cells = mask
                .cells
                .iter()
                .zip(&dod.values)
                .filter(|(m, v)| **m && v.is_finite())
                .count();
            if measured_cells == 0 {
                // The region lies outside what both DEMs cover: nothing measured, said so.
                rows.push(RegionVolume {
                    region: region.name.clone(),
                    from: v.from.clone(),
                    to: v.to.clone(),
                    true_m3: v.volume_m3,
                    measured_m3: f64::NAN,
                    sigma_m3: f64::NAN,
                    coverage: 0.0,
                });
                continue;
            }
            let measured = volumes(dod, Some(&mask), *options).map_err(change_err(context))?;
            rows.push(RegionVolume {
                region: region.name.clone(),
                from: v.from.clone(),
                to: v.to.clone(),
                true_m3: v.volume_m3,
                measured_m3: measured.net,
                sigma_m3: measured.sigma_net,
                coverage: measured.cells as f64 / inside as f64,
            });
        }
    }
    Ok(rows)
}

/// An epoch's DEM against its true surface (`truth/dem_<epoch>.tif`) over the cells measured
/// from the cloud: (cells, mean, median, NMAD), metres.
pub fn epoch_dem_error(
    layout: &Layout,
    epoch: &str,
) -> Result<Option<(usize, f64, f64, f64)>, EvalError> {
    let truth = true_dem(layout, epoch)?;
    let dem = timesift_io::geotiff::read_f32(&layout.dem(epoch))?;
    let count = timesift_io::geotiff::read_f32(&layout.dem_count(epoch))?;
    let errors = dem_height_errors(&dem, &count, &truth, |_, _| true);
    Ok(timesift_change::stats::statistics(errors.iter().copied())
        .map(|s| (s.count, s.mean, s.median, s.nmad)))
}
