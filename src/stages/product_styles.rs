//! How QGIS draws each kind of product, in one place. The stage that writes a raster writes its
//! style beside it (`.qml`, which QGIS takes when the raster is added alone); the report
//! stage's `out/timesift.qgs` draws every product the same way.

use timesift_io::qgis::RasterStyle;

/// A DEM: a terrain ramp over its 2nd to 98th height percentiles.
pub(crate) fn dem(heights: &[f32], nodata: Option<f64>) -> RasterStyle {
    RasterStyle::terrain_fitted(heights, nodata)
}

/// Points per cell, the heights' spread: a sequential ramp from zero.
pub(crate) fn amount(values: &[f32], nodata: Option<f64>) -> RasterStyle {
    RasterStyle::sequential_fitted(values, nodata)
}

/// A DoD: blue (down) through white to red (up) about zero, the LoD95 band not drawn.
pub(crate) fn dod(values: &[f32], nodata: Option<f64>, lod95: Option<f64>) -> RasterStyle {
    RasterStyle::diverging_fitted(values, nodata, lod95)
}

/// An orthomosaic: RGB, band 4 its coverage.
pub(crate) fn ortho() -> RasterStyle {
    RasterStyle::Rgb { alpha: true }
}

fn flags(label: &str, colour: [u8; 3]) -> RasterStyle {
    RasterStyle::Classes(vec![
        (0, "no".to_string(), None),
        (1, label.to_string(), Some(colour)),
    ])
}

/// `dem_filled.tif`: the cells filled by interpolation, in orange.
pub(crate) fn filled() -> RasterStyle {
    flags("filled", [230, 140, 20])
}

/// `significant.tif`: the cells beyond the LoD95, dark grey.
pub(crate) fn significant() -> RasterStyle {
    flags("beyond the LoD95", [60, 60, 60])
}

/// `stable_found.tif`: the ground the align stage found unchanged, green.
pub(crate) fn stable_found() -> RasterStyle {
    flags("unchanged", [40, 160, 60])
}
