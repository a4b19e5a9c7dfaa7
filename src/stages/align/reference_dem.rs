//! `[align] reference_dem`: the modern DEM read from its GeoTIFF, put in the project's CRS when
//! it is in another one, and moved into the block's local frame.

use std::path::Path;
use std::sync::Arc;

use timesift_align::ReferenceDem;
use timesift_change::grid::{Dem, Grid};
use timesift_io::coords::{Crs, Projector};
use timesift_io::geotiff::{GeoTransform, read_f32};

use super::input::LocalFrame;
use super::stage_error;
use crate::{Project, ProjectError};

/// Most cells of a DEM put in the project's CRS: a 1 m lidar DEM of 7 × 7 km.
const MAX_REPROJECTED_CELLS: usize = 50_000_000;

/// Metres per degree of latitude (a geographic DEM's cell in metres, for the grid it is put on).
const METRES_PER_DEGREE: f64 = 111_320.0;

/// The project's reference DEM in the block's frame, when `[align] reference_dem` names one.
pub(super) fn reference_dem(
    project: &Project,
    frame: &LocalFrame,
) -> Result<Option<Arc<ReferenceDem>>, ProjectError> {
    let Some(name) = &project.config.align.reference_dem else {
        return Ok(None);
    };
    let path = project.dir.join(name);
    let expected = "a single-band north-up GeoTIFF of heights was expected";
    let raster = read_f32(&path)
        .map_err(|e| stage_error(format!("[align] reference_dem: {e} ({expected})")))?;
    let dem = Dem::from_raster(raster, None)
        .map_err(|e| stage_error(format!("{}: {e} ({expected})", path.display())))?;
    let crs: Crs = project
        .config
        .crs
        .parse()
        .map_err(|e: String| stage_error(format!("crs: {e}")))?;
    let dem = match (dem.grid.crs, crs) {
        (dem_crs, project_crs) if dem_crs == project_crs => square(&path, dem)?,
        (Crs::Local, _) => {
            tracing::warn!(
                "{}: the reference DEM declares no CRS; taken to be the project's ({crs})",
                path.display()
            );
            square(&path, dem)?
        }
        (dem_crs, Crs::Local) => {
            return Err(stage_error(format!(
                "{}: the reference DEM is in {dem_crs} but the project's crs is local: give the \
                 project its CRS, or the DEM in the project's frame",
                path.display()
            )));
        }
        (_, project_crs) => reprojected(&path, &dem, project_crs)?,
    };
    let origin = frame.origin;
    let t = dem.grid.transform;
    let heights = dem
        .values
        .iter()
        .map(|&h| (f64::from(h) - origin.z) as f32)
        .collect();
    let reference = ReferenceDem::new(
        [t.origin_x - origin.x, t.origin_y - origin.y],
        t.pixel_width,
        [dem.grid.width, dem.grid.height],
        heights,
        project.config.align.reference_dem_sigma,
    )
    .map_err(|e| stage_error(format!("{}: {e}", path.display())))?;
    if reference.valid_cells() == 0 {
        return Err(stage_error(format!(
            "{}: the reference DEM has no height (every cell nodata)",
            path.display()
        )));
    }
    tracing::info!(
        path = %path.display(),
        cell = t.pixel_width,
        cells = reference.valid_cells(),
        sigma = reference.sigma(),
        "reference DEM"
    );
    Ok(Some(Arc::new(reference)))
}

/// The DEM as it is, already in the project's CRS, when its cells are square.
fn square(path: &Path, dem: Dem) -> Result<Dem, ProjectError> {
    let t = dem.grid.transform;
    if (t.pixel_width + t.pixel_height).abs() > 1e-9 * t.pixel_width.abs() {
        return Err(stage_error(format!(
            "{}: the reference DEM's cells are {} × {}; square north-up cells were expected",
            path.display(),
            t.pixel_width,
            -t.pixel_height
        )));
    }
    Ok(dem)
}

/// The DEM resampled (bilinear) onto a grid of the project's CRS covering it, at its own cell
/// size in metres.
fn reprojected(path: &Path, dem: &Dem, project_crs: Crs) -> Result<Dem, ProjectError> {
    let err = |e: timesift_io::IoError| stage_error(format!("{}: {e}", path.display()));
    let dem_crs = dem.grid.crs;
    let to_project = Projector::new(project_crs).map_err(err)?;
    let geographic = dem_crs.is_geographic();
    let from_dem = match geographic {
        true => None,
        false => Some(Projector::new(dem_crs).map_err(err)?),
    };
    // DEM CRS → latitude, longitude → project CRS, and back.
    let to_latlon = |x: f64, y: f64| match &from_dem {
        Some(p) => p.unproject(x, y),
        None => Ok((y, x)),
    };
    let from_latlon = |lat: f64, lon: f64| match &from_dem {
        Some(p) => p.project(lat, lon),
        None => Ok((lon, lat)),
    };
    let t = dem.grid.transform;
    let (w, h) = (dem.grid.width as f64, dem.grid.height as f64);
    // The DEM's outline (edges sampled every tenth) in the project's CRS.
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for k in 0..=10 {
        let f = k as f64 / 10.0;
        for (c, r) in [(f * w, 0.0), (f * w, h), (0.0, f * h), (w, f * h)] {
            let (x, y) = t.pixel_to_world(c, r);
            let (lat, lon) = to_latlon(x, y).map_err(err)?;
            let (e, n) = to_project.project(lat, lon).map_err(err)?;
            lo = [lo[0].min(e), lo[1].min(n)];
            hi = [hi[0].max(e), hi[1].max(n)];
        }
    }
    let cell = match geographic {
        true => {
            let (lat, _) = to_latlon(t.origin_x, t.origin_y).map_err(err)?;
            let dx = t.pixel_width * METRES_PER_DEGREE * lat.to_radians().cos();
            dx.min(-t.pixel_height * METRES_PER_DEGREE)
        }
        false => t.pixel_width.min(-t.pixel_height),
    };
    let width = ((hi[0] - lo[0]) / cell).ceil() as usize;
    let height = ((hi[1] - lo[1]) / cell).ceil() as usize;
    if !(cell > 0.0) || width.saturating_mul(height) > MAX_REPROJECTED_CELLS {
        return Err(stage_error(format!(
            "{}: the reference DEM would take {width} × {height} cells of {cell:.2} m in \
             {project_crs}; crop it to the project's area (at most {MAX_REPROJECTED_CELLS} cells)",
            path.display()
        )));
    }
    let values = (0..height)
        .flat_map(|r| (0..width).map(move |c| (r, c)))
        .map(|(r, c)| {
            let e = lo[0] + (c as f64 + 0.5) * cell;
            let n = hi[1] - (r as f64 + 0.5) * cell;
            let at = to_project
                .unproject(e, n)
                .and_then(|(lat, lon)| from_latlon(lat, lon));
            at.map_or(f32::NAN, |(x, y)| dem.bilinear(x, y) as f32)
        })
        .collect();
    tracing::info!(
        from = %dem_crs,
        to = %project_crs,
        width,
        height,
        cell,
        "reference DEM put in the project's CRS"
    );
    Ok(Dem {
        grid: Grid {
            transform: GeoTransform {
                origin_x: lo[0],
                origin_y: hi[1],
                pixel_width: cell,
                pixel_height: -cell,
            },
            width,
            height,
            crs: project_crs,
        },
        values,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use timesift_io::geotiff::{GeoRaster, GeoReference};

    /// A 100 × 80 grid of 10 m cells in UTM 31N near Paris, heights a plane of the UTM
    /// coordinates; `holes` cells nodata (-9999).
    fn utm_plane(pixel_height: f64) -> Dem {
        let (width, height) = (100, 80);
        let t = GeoTransform {
            origin_x: 450_000.0,
            origin_y: 5_400_000.0,
            pixel_width: 10.0,
            pixel_height,
        };
        let data = (0..height)
            .flat_map(|r| (0..width).map(move |c| (r, c)))
            .map(|(r, c)| {
                let (e, n) = t.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
                if c == 50 && r == 40 {
                    -9999.0
                } else {
                    plane(e, n) as f32
                }
            })
            .collect();
        let raster = GeoRaster {
            width,
            height,
            bands: 1,
            data,
            georef: GeoReference {
                transform: t,
                crs: Crs::Epsg(32631),
                nodata: Some(-9999.0),
                pixel_is_point: false,
            },
        };
        Dem::from_raster(raster, None).unwrap()
    }

    fn plane(e: f64, n: f64) -> f64 {
        100.0 + 0.02 * (e - 450_000.0) - 0.01 * (n - 5_400_000.0)
    }

    #[test]
    fn a_dem_in_another_crs_is_put_in_the_projects_with_its_heights_where_they_belong() {
        let path = Path::new("dem.tif");
        let dem = reprojected(path, &utm_plane(-10.0), Crs::Epsg(2154)).unwrap();
        let (grid, t) = (&dem.grid, dem.grid.transform);
        let lambert = Projector::new(Crs::Epsg(2154)).unwrap();
        let utm = Projector::new(Crs::Epsg(32631)).unwrap();
        let (mut checked, mut holes) = (0, 0);
        for r in (0..grid.height).step_by(7) {
            for c in (0..grid.width).step_by(7) {
                let h = dem.values[r * grid.width + c];
                let (x, y) = t.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
                let (lat, lon) = lambert.unproject(x, y).unwrap();
                let (e, n) = utm.project(lat, lon).unwrap();
                let inside =
                    (450_005.0..450_995.0).contains(&e) && (5_399_205.0..5_399_995.0).contains(&n);
                let near_hole = (e - 450_505.0).abs() < 20.0 && (n - 5_399_595.0).abs() < 20.0;
                if !inside || near_hole {
                    holes += usize::from(near_hole && h.is_nan());
                    continue;
                }
                assert!(
                    (f64::from(h) - plane(e, n)).abs() < 1e-3,
                    "at ({e}, {n}): {h} against {}",
                    plane(e, n)
                );
                checked += 1;
            }
        }
        assert!(checked > 100, "{checked}");
        // The nodata cell is no height in the grid either.
        assert!(dem.values.iter().any(|h| h.is_nan()), "{holes}");
        assert!((t.pixel_width - 10.0).abs() < 1e-9);
    }

    #[test]
    fn cells_that_are_not_square_are_refused_with_the_file_named() {
        let e = square(Path::new("dem.tif"), utm_plane(-5.0)).expect_err("non-square cells");
        assert!(
            e.to_string().contains("dem.tif") && e.to_string().contains("square"),
            "{e}"
        );
        assert!(square(Path::new("dem.tif"), utm_plane(-10.0)).is_ok());
    }
}
