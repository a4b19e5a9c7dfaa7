//! The products as QGIS opens them: `out/timesift.qgs`, one project of every epoch's DEM
//! (terrain ramp under its hillshade), ortho, count, spread and filled cells, and every DoD (a
//! diverging ramp about zero with the LoD95 band left out), in groups, drawn as
//! [`super::product_styles`] says. Written by the report stage, after every product exists.
//!
//! Each product's `.qml` is written by the stage that writes the product (a unit of work never
//! writes another's files); the report stage only adds a style where a product has none, as
//! the products of a project made before styles existed.

use std::path::Path;

use timesift_io::coords::Crs;
use timesift_io::geotiff::{GeoTransform, read_f32, read_grid};
use timesift_io::qgis::{ProjectGroup, ProjectLayer, RasterStyle, write_qgs, write_qml};

use super::{epoch_pairs, product_styles};
use crate::report::read_json;
use crate::{Project, ProjectError};

fn extent_of(t: &GeoTransform, width: usize, height: usize) -> [f64; 4] {
    let x1 = t.origin_x + width as f64 * t.pixel_width;
    let y1 = t.origin_y + height as f64 * t.pixel_height;
    [
        t.origin_x.min(x1),
        t.origin_y.min(y1),
        t.origin_x.max(x1),
        t.origin_y.max(y1),
    ]
}

/// A layer of a product in `out/`, its sidecar written; `None` when the product is absent.
struct LayerMaker<'a> {
    out: &'a Path,
    extents: Vec<[f64; 4]>,
}

impl LayerMaker<'_> {
    /// A single-band product: decoded for its range, styled by `style`.
    fn band(
        &mut self,
        relative: &str,
        name: String,
        visible: bool,
        style: impl Fn(&[f32], Option<f64>) -> RasterStyle,
    ) -> Result<Option<ProjectLayer>, ProjectError> {
        let path = self.out.join(relative);
        if !path.is_file() {
            return Ok(None);
        }
        let raster = read_f32(&path)?;
        let style = style(&raster.data, raster.georef.nodata);
        let extent = extent_of(&raster.georef.transform, raster.width, raster.height);
        self.layer(&path, relative, name, visible, style, extent)
    }

    /// An orthomosaic (RGBA: the ortho stage writes band 4 as coverage): only its header is read.
    fn image(
        &mut self,
        relative: &str,
        name: String,
        visible: bool,
    ) -> Result<Option<ProjectLayer>, ProjectError> {
        let path = self.out.join(relative);
        if !path.is_file() {
            return Ok(None);
        }
        let grid = read_grid(&path)?;
        let extent = extent_of(&grid.georef.transform, grid.width, grid.height);
        self.layer(
            &path,
            relative,
            name,
            visible,
            product_styles::ortho(),
            extent,
        )
    }

    /// The layer of a product; its style written beside it when it has none.
    fn layer(
        &mut self,
        path: &Path,
        relative: &str,
        name: String,
        visible: bool,
        style: RasterStyle,
        extent: [f64; 4],
    ) -> Result<Option<ProjectLayer>, ProjectError> {
        if !path.with_extension("qml").is_file() {
            write_qml(path, &style)?;
        }
        self.extents.push(extent);
        Ok(Some(ProjectLayer {
            name,
            path: relative.to_string(),
            style,
            extent,
            visible,
        }))
    }
}

/// What the report stage wrote for QGIS: the project file and its layer count.
pub(crate) struct QgisFiles {
    pub layers: usize,
}

/// Writes every product's `.qml` and `out/timesift.qgs`.
pub(crate) fn write_qgis_files(project: &Project) -> Result<QgisFiles, ProjectError> {
    let layout = project.layout();
    let out = layout.out_dir();
    let mut maker = LayerMaker {
        out: &out,
        extents: Vec::new(),
    };
    let mut groups = Vec::new();
    let mut change = Vec::new();
    for (k, (a, b)) in epoch_pairs(project).iter().enumerate() {
        let dir = format!("change/{a}__{b}");
        // The LoD95 of the pair's statistics (`DemReport::lod95`), read as plain JSON: this
        // module is also the `compare` command's.
        let lod95 = read_json::<serde_json::Value>(&layout.change_stats(a, b))
            .ok()
            .and_then(|r| r.get("lod95").and_then(serde_json::Value::as_f64));
        let dod = maker.band(
            &format!("{dir}/dod.tif"),
            format!("DoD {a} → {b}"),
            k == 0,
            |v, n| product_styles::dod(v, n, lod95),
        )?;
        let significant = maker.band(
            &format!("{dir}/significant.tif"),
            format!("beyond LoD95 {a} → {b}"),
            false,
            |_, _| product_styles::significant(),
        )?;
        change.extend(dod.into_iter().chain(significant));
    }
    if !change.is_empty() {
        groups.push(ProjectGroup {
            name: "change".into(),
            layers: change,
        });
    }
    for (k, epoch) in project.epochs.iter().enumerate() {
        let e = &epoch.name;
        let dir = format!("epochs/{e}");
        let first = k == 0;
        let mut layers = Vec::new();
        if let Some(dem) = maker.band(
            &format!("{dir}/dem.tif"),
            format!("DEM {e}"),
            first,
            RasterStyle::terrain_fitted,
        )? {
            layers.push(ProjectLayer {
                name: format!("hillshade {e}"),
                style: RasterStyle::Hillshade,
                ..dem.clone()
            });
            layers.push(dem);
        }
        let others = [
            maker.image(&format!("{dir}/ortho.tif"), format!("ortho {e}"), false)?,
            maker.band(
                &format!("{dir}/dem_count.tif"),
                format!("points per cell {e}"),
                false,
                RasterStyle::sequential_fitted,
            )?,
            maker.band(
                &format!("{dir}/dem_std.tif"),
                format!("height spread {e}"),
                false,
                RasterStyle::sequential_fitted,
            )?,
            maker.band(
                &format!("{dir}/dem_filled.tif"),
                format!("filled cells {e}"),
                false,
                |_, _| product_styles::filled(),
            )?,
        ];
        layers.extend(others.into_iter().flatten());
        if !layers.is_empty() {
            groups.push(ProjectGroup {
                name: e.clone(),
                layers,
            });
        }
    }
    if let Some(found) = maker.band(
        "stable_found.tif",
        "ground found unchanged".into(),
        false,
        |_, _| product_styles::stable_found(),
    )? {
        groups.push(ProjectGroup {
            name: "orientation".into(),
            layers: vec![found],
        });
    }
    let layers = groups.iter().map(|g| g.layers.len()).sum();
    let Some(extent) = maker.extents.iter().copied().reduce(|a, b| {
        [
            a[0].min(b[0]),
            a[1].min(b[1]),
            a[2].max(b[2]),
            a[3].max(b[3]),
        ]
    }) else {
        return Ok(QgisFiles { layers: 0 });
    };
    let crs: Crs = project.config.crs.parse().unwrap_or(Crs::Local);
    write_qgs(&out.join("timesift.qgs"), "timesift", crs, extent, &groups)?;
    Ok(QgisFiles { layers })
}
