//! The products as QGIS opens them: a `.qml` style beside every GeoTIFF product and
//! `out/timesift.qgs`, one project of every epoch's DEM (terrain ramp under its hillshade),
//! ortho, count, spread and filled cells, and every DoD (a diverging ramp about zero with the
//! LoD95 band left out), in groups. Written by the report stage, after every product exists.
//!
//! The ramps are fitted to the data (the 2nd and 98th percentiles of the heights; ±the 98th
//! percentile of |DoD|, at least twice the LoD95), so the files are rewritten on every report.

use std::path::Path;

use timesift_io::coords::Crs;
use timesift_io::geotiff::{GeoTransform, read_f32, read_grid};
use timesift_io::qgis::{ProjectGroup, ProjectLayer, RasterStyle, write_qgs, write_qml};

use super::epoch_pairs;
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
        self.styled(&path, relative, name, visible, style, extent)
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
        let style = RasterStyle::Rgb { alpha: true };
        self.styled(&path, relative, name, visible, style, extent)
    }

    /// Writes the product's style beside it; the layer of it.
    fn styled(
        &mut self,
        path: &Path,
        relative: &str,
        name: String,
        visible: bool,
        style: RasterStyle,
        extent: [f64; 4],
    ) -> Result<Option<ProjectLayer>, ProjectError> {
        write_qml(path, &style)?;
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

fn flags(label: &str, colour: [u8; 3]) -> impl Fn(&[f32], Option<f64>) -> RasterStyle {
    let classes = vec![
        (0, "no".to_string(), None),
        (1, label.to_string(), Some(colour)),
    ];
    move |_, _| RasterStyle::Classes(classes.clone())
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
            |v, n| RasterStyle::diverging_fitted(v, n, lod95),
        )?;
        let significant = maker.band(
            &format!("{dir}/significant.tif"),
            format!("beyond LoD95 {a} → {b}"),
            false,
            flags("beyond the LoD95", [60, 60, 60]),
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
                flags("filled", [230, 140, 20]),
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
        flags("unchanged", [40, 160, 60]),
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
