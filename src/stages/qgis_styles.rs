//! The products as QGIS opens them: `out/timesift.qgs`, one project of every epoch's DEM
//! (terrain ramp under its hillshade), ortho, count, spread and filled cells, and every DoD (a
//! diverging ramp about zero with the LoD95 band left out), in groups, drawn as
//! [`super::product_styles`] says. Written by the report stage, after every product exists.
//!
//! Each product's `.qml` is written by the stage that writes the product (a unit of work never
//! writes another's files), and the project embeds it as it is, so the report reads only the
//! rasters' headers. Only a product without a style (made before styles existed) is decoded, to
//! fit its style, which is then written beside it.

use std::path::Path;

use timesift_change::grid::Grid;
use timesift_io::coords::Crs;
use timesift_io::geotiff::{read_f32, read_grid};
use timesift_io::qgis::{
    LayerStyle, ProjectGroup, ProjectLayer, RasterStyle, read_qml, write_qgs, write_qml,
};

use super::{epoch_pairs, product_styles};
use crate::commands::compare::DemReport;
use crate::report::read_json;
use crate::{Project, ProjectError};

/// The layers of the products under `out/`.
struct LayerMaker<'a> {
    out: &'a Path,
}

impl LayerMaker<'_> {
    /// The layer of the product at `relative` (`None` when it is absent), drawn by the style
    /// beside it; without one, by `style`'s (given the product's path), written beside it.
    fn layer(
        &self,
        relative: &str,
        name: String,
        visible: bool,
        style: impl FnOnce(&Path) -> Result<RasterStyle, ProjectError>,
    ) -> Result<Option<ProjectLayer>, ProjectError> {
        let path = self.out.join(relative);
        if !path.is_file() {
            return Ok(None);
        }
        let grid = read_grid(&path)?;
        let (xmin, ymin, xmax, ymax) = Grid {
            transform: grid.georef.transform,
            width: grid.width,
            height: grid.height,
            crs: grid.georef.crs,
        }
        .extent();
        let style = match read_qml(&path)? {
            Some(style) => style,
            None => {
                let style = style(&path)?;
                write_qml(&path, &style)?;
                LayerStyle::Style(style)
            }
        };
        Ok(Some(ProjectLayer {
            name,
            path: relative.to_string(),
            style,
            extent: [xmin, ymin, xmax, ymax],
            visible,
        }))
    }
}

/// A style fitted to a product's values, which are decoded for it.
fn fitted(
    fit: impl FnOnce(&[f32], Option<f64>) -> RasterStyle,
) -> impl FnOnce(&Path) -> Result<RasterStyle, ProjectError> {
    move |path| {
        let raster = read_f32(path)?;
        Ok(fit(&raster.data, raster.georef.nodata))
    }
}

/// What the report stage wrote for QGIS: the project file's layer count.
pub(crate) struct QgisFiles {
    pub layers: usize,
}

/// Writes `out/timesift.qgs` (and a `.qml` beside any product without one).
pub(crate) fn write_qgis_files(project: &Project) -> Result<QgisFiles, ProjectError> {
    let layout = project.layout();
    let out = layout.out_dir();
    let maker = LayerMaker { out: &out };
    let mut groups = Vec::new();
    let mut change = Vec::new();
    for (k, (a, b)) in epoch_pairs(project).iter().enumerate() {
        let dir = format!("change/{a}__{b}");
        let dod = maker.layer(
            &format!("{dir}/dod.tif"),
            format!("DoD {a} → {b}"),
            k == 0,
            fitted(|v, n| {
                let lod95 = read_json::<DemReport>(&layout.change_stats(a, b))
                    .ok()
                    .and_then(|r| r.lod95);
                product_styles::dod(v, n, lod95)
            }),
        )?;
        let significant = maker.layer(
            &format!("{dir}/significant.tif"),
            format!("beyond LoD95 {a} → {b}"),
            false,
            |_| Ok(product_styles::significant()),
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
        let mut layers = Vec::new();
        if let Some(dem) = maker.layer(
            &format!("{dir}/dem.tif"),
            format!("DEM {e}"),
            k == 0,
            fitted(product_styles::dem),
        )? {
            layers.push(ProjectLayer {
                name: format!("hillshade {e}"),
                style: LayerStyle::Style(RasterStyle::Hillshade),
                ..dem.clone()
            });
            layers.push(dem);
        }
        let others = [
            maker.layer(
                &format!("{dir}/ortho.tif"),
                format!("ortho {e}"),
                false,
                |_| Ok(product_styles::ortho()),
            )?,
            maker.layer(
                &format!("{dir}/dem_count.tif"),
                format!("points per cell {e}"),
                false,
                fitted(product_styles::amount),
            )?,
            maker.layer(
                &format!("{dir}/dem_std.tif"),
                format!("height spread {e}"),
                false,
                fitted(product_styles::amount),
            )?,
            maker.layer(
                &format!("{dir}/dem_filled.tif"),
                format!("filled cells {e}"),
                false,
                |_| Ok(product_styles::filled()),
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
    if let Some(found) = maker.layer(
        "stable_found.tif",
        "ground found unchanged".into(),
        false,
        |_| Ok(product_styles::stable_found()),
    )? {
        groups.push(ProjectGroup {
            name: "orientation".into(),
            layers: vec![found],
        });
    }
    let all = || groups.iter().flat_map(|g| &g.layers);
    let Some(extent) = all().map(|l| l.extent).reduce(|a, b| {
        [
            a[0].min(b[0]),
            a[1].min(b[1]),
            a[2].max(b[2]),
            a[3].max(b[3]),
        ]
    }) else {
        return Ok(QgisFiles { layers: 0 });
    };
    let layers = all().count();
    let crs: Crs = project.config.crs.parse().unwrap_or(Crs::Local);
    write_qgs(&out.join("timesift.qgs"), "timesift", crs, extent, &groups)?;
    Ok(QgisFiles { layers })
}
