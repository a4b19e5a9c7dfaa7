//! QGIS styles and projects: a `.qml` sidecar beside a GeoTIFF (same base name, which QGIS loads
//! when the raster is added) and a `.qgs` project of many rasters in groups.
//!
//! Why here: the products should open in QGIS looking like what they are — a DEM as terrain, a
//! DoD as signed change with what is below the level of detection left out — without a user
//! styling every layer of every epoch by hand. The XML follows QGIS 3's raster renderer
//! elements (`singlebandpseudocolor`, `hillshade`, `multibandcolor`, `paletted`); QGIS fills in
//! what a file leaves out with its defaults.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::IoError;
use crate::coords::Crs;
use crate::fsutil::write_bytes_atomically;

/// How a raster is drawn.
#[derive(Debug, Clone, PartialEq)]
pub enum RasterStyle {
    /// Heights: a terrain ramp (green lowlands to brown and white heights) from `min` to `max`.
    Terrain {
        /// Height at the ramp's first colour.
        min: f64,
        /// Height at its last.
        max: f64,
    },
    /// Signed change: blue (lowering) through white to red (raising), symmetric about zero up to
    /// ±`limit`; values within ±`transparent_within` (the LoD95) are not drawn.
    Diverging {
        /// The ramp's end, both ways.
        limit: f64,
        /// Half-width of the band left transparent about zero.
        transparent_within: Option<f64>,
    },
    /// Amounts (counts, spreads): a sequential ramp from `min` to `max`.
    Sequential {
        /// Value at the light end.
        min: f64,
        /// Value at the dark end.
        max: f64,
    },
    /// The shaded relief of heights, drawn over their `Terrain` layer by multiplying.
    Hillshade,
    /// An RGB image (bands 1–3), with band 4 as alpha when `alpha`.
    Rgb {
        /// Band 4 is alpha.
        alpha: bool,
    },
    /// Classes of integer values: value, label, colour (`None`: not drawn).
    Classes(Vec<(i64, String, Option<[u8; 3]>)>),
}

impl RasterStyle {
    /// [`RasterStyle::Terrain`] over the 2nd to 98th percentile of the values.
    pub fn terrain_fitted(values: &[f32], nodata: Option<f64>) -> RasterStyle {
        let (min, max) = percentile_range(values, nodata).unwrap_or((0.0, 1.0));
        RasterStyle::Terrain { min, max }
    }

    /// [`RasterStyle::Sequential`] from zero to the 98th percentile of the values.
    pub fn sequential_fitted(values: &[f32], nodata: Option<f64>) -> RasterStyle {
        let max = percentile_range(values, nodata).map_or(1.0, |(_, hi)| hi);
        RasterStyle::Sequential { min: 0.0, max }
    }

    /// [`RasterStyle::Diverging`] to ±the 98th percentile of |value|, and at least twice
    /// `transparent_within`, so that the band left out is never the whole ramp.
    pub fn diverging_fitted(
        values: &[f32],
        nodata: Option<f64>,
        transparent_within: Option<f64>,
    ) -> RasterStyle {
        let magnitudes: Vec<f32> = values
            .iter()
            .filter(|v| nodata.is_none_or(|n| f64::from(**v) != n))
            .map(|v| v.abs())
            .collect();
        let largest = percentile_range(&magnitudes, None).map_or(1.0, |(_, hi)| hi);
        RasterStyle::Diverging {
            limit: largest.max(2.0 * transparent_within.unwrap_or(0.0)),
            transparent_within,
        }
    }
}

/// The 2nd and 98th percentiles of the values, nodata and non-finite values left out; `None`
/// when none is left.
pub fn percentile_range(values: &[f32], nodata: Option<f64>) -> Option<(f64, f64)> {
    let mut kept: Vec<f32> = values
        .iter()
        .copied()
        .filter(|v| v.is_finite() && nodata.is_none_or(|n| f64::from(*v) != n))
        .collect();
    if kept.is_empty() {
        return None;
    }
    let mut at = |q: f64| {
        let k = ((kept.len() - 1) as f64 * q).round() as usize;
        f64::from(*kept.select_nth_unstable_by(k, f32::total_cmp).1)
    };
    let low = at(0.02);
    Some((low, at(0.98)))
}

/// The terrain ramp: relative position, colour.
const TERRAIN: [(f64, &str); 5] = [
    (0.0, "#1a9641"),
    (0.25, "#a6d96a"),
    (0.5, "#ffffbf"),
    (0.75, "#c0835c"),
    (1.0, "#f5f5f5"),
];
/// Blue–white–red, from −limit to +limit.
const DIVERGING: [(f64, &str); 5] = [
    (-1.0, "#2166ac"),
    (-0.5, "#92c5de"),
    (0.0, "#f7f7f7"),
    (0.5, "#f4a582"),
    (1.0, "#b2182b"),
];
/// Light yellow to dark blue.
const SEQUENTIAL: [(f64, &str); 4] = [
    (0.0, "#ffffcc"),
    (0.33, "#a1dab4"),
    (0.66, "#41b6c4"),
    (1.0, "#225ea8"),
];

/// QGIS's blend mode of a layer drawn by multiplying with what is below it.
const BLEND_MULTIPLY: u32 = 6;

fn ramp_items(out: &mut String, stops: impl Iterator<Item = (f64, &'static str)>) {
    for (value, colour) in stops {
        let _ = writeln!(
            out,
            "          <item value=\"{value}\" color=\"{colour}\" alpha=\"255\" label=\"{value:.3}\"/>"
        );
    }
}

fn pseudocolor(min: f64, max: f64, stops: &str, transparency: &str) -> String {
    format!(
        "    <rasterrenderer type=\"singlebandpseudocolor\" band=\"1\" opacity=\"1\" \
         alphaBand=\"-1\" classificationMin=\"{min}\" classificationMax=\"{max}\" nodataColor=\"\">\n\
         {transparency}      <rastershader>\n        <colorrampshader colorRampType=\"INTERPOLATED\" \
         classificationMode=\"1\" clip=\"0\" minimumValue=\"{min}\" maximumValue=\"{max}\">\n\
         {stops}        </colorrampshader>\n      </rastershader>\n    </rasterrenderer>\n"
    )
}

/// The `<rasterrenderer>` element of a style.
fn renderer(style: &RasterStyle) -> String {
    match style {
        RasterStyle::Terrain { min, max } => stretched(&TERRAIN, *min, *max),
        RasterStyle::Sequential { min, max } => stretched(&SEQUENTIAL, *min, *max),
        RasterStyle::Diverging {
            limit,
            transparent_within,
        } => {
            let limit = if limit.is_finite() && *limit > 0.0 {
                *limit
            } else {
                1.0
            };
            let mut stops = String::new();
            ramp_items(&mut stops, DIVERGING.iter().map(|&(t, c)| (t * limit, c)));
            let transparency = match transparent_within {
                Some(band) if band.is_finite() && *band > 0.0 => format!(
                    "      <rasterTransparency>\n        <singleValuePixelList>\n          \
                     <pixelListEntry min=\"{}\" max=\"{band}\" percentTransparent=\"100\"/>\n        \
                     </singleValuePixelList>\n      </rasterTransparency>\n",
                    -band
                ),
                _ => String::new(),
            };
            pseudocolor(-limit, limit, &stops, &transparency)
        }
        RasterStyle::Hillshade => {
            "    <rasterrenderer type=\"hillshade\" band=\"1\" opacity=\"1\" \
             alphaBand=\"-1\" azimuth=\"315\" angle=\"45\" zfactor=\"1\" multidirection=\"0\"/>\n"
                .to_string()
        }
        RasterStyle::Rgb { alpha } => format!(
            "    <rasterrenderer type=\"multibandcolor\" redBand=\"1\" greenBand=\"2\" \
             blueBand=\"3\" alphaBand=\"{}\" opacity=\"1\"/>\n",
            if *alpha { 4 } else { -1 }
        ),
        RasterStyle::Classes(classes) => {
            let mut entries = String::new();
            for (value, label, colour) in classes {
                let (hex, alpha) = match colour {
                    Some([r, g, b]) => (format!("#{r:02x}{g:02x}{b:02x}"), 255),
                    None => ("#000000".to_string(), 0),
                };
                let _ = writeln!(
                    entries,
                    "        <paletteEntry value=\"{value}\" color=\"{hex}\" alpha=\"{alpha}\" \
                     label=\"{}\"/>",
                    escape(label)
                );
            }
            format!(
                "    <rasterrenderer type=\"paletted\" band=\"1\" opacity=\"1\" alphaBand=\"-1\">\n      \
                 <colorPalette>\n{entries}      </colorPalette>\n    </rasterrenderer>\n"
            )
        }
    }
}

/// A ramp of relative stops stretched over `min..max`.
fn stretched(ramp: &[(f64, &'static str)], min: f64, max: f64) -> String {
    let (min, max) = widened(min, max);
    let mut stops = String::new();
    ramp_items(
        &mut stops,
        ramp.iter().map(|&(t, c)| (min + t * (max - min), c)),
    );
    pseudocolor(min, max, &stops, "")
}

/// A range with room: a flat raster still gets a ramp.
fn widened(min: f64, max: f64) -> (f64, f64) {
    match (min.is_finite(), max.is_finite()) {
        (true, true) if max > min => (min, max),
        (true, true) => (min - 0.5, min + 0.5),
        _ => (0.0, 1.0),
    }
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A layer's `<pipe>` and blend mode: what a `.qml` holds and a project embeds per layer.
fn pipe_and_blend(style: &RasterStyle) -> String {
    let blend = if *style == RasterStyle::Hillshade {
        BLEND_MULTIPLY
    } else {
        0
    };
    format!(
        "  <pipe>\n{}    <brightnesscontrast brightness=\"0\" contrast=\"0\" gamma=\"1\"/>\n    \
         <huesaturation saturation=\"0\" grayscaleMode=\"0\" colorizeOn=\"0\"/>\n  </pipe>\n  \
         <blendMode>{blend}</blendMode>\n",
        renderer(style)
    )
}

/// The text of a `.qml` style file.
pub fn qml(style: &RasterStyle) -> String {
    format!(
        "<!DOCTYPE qgis PUBLIC 'http://mrcc.com/qgis.dtd' 'SYSTEM'>\n<qgis version=\"3.22.0\" \
         styleCategories=\"AllStyleCategories\">\n{}</qgis>\n",
        pipe_and_blend(style)
    )
}

/// Writes the style of the raster at `raster` beside it: the same path with `.qml`.
pub fn write_qml(raster: &Path, style: &RasterStyle) -> Result<PathBuf, IoError> {
    let path = raster.with_extension("qml");
    write_bytes_atomically(&path, qml(style).as_bytes())?;
    Ok(path)
}

/// The style beside the raster at `raster` (its `.qml`), as a project layer takes it: the
/// elements inside the file's `<qgis>` element, verbatim. `None` when there is no such file. A
/// style a user saved from QGIS over timesift's is taken as it is.
pub fn read_qml(raster: &Path) -> Result<Option<LayerStyle>, IoError> {
    let path = raster.with_extension("qml");
    if !path.is_file() {
        return Ok(None);
    }
    let text = crate::fsutil::read_text(&path)?;
    let body = text
        .find("<qgis")
        .and_then(|open| text[open..].find('>').map(|end| open + end + 1))
        .zip(text.rfind("</qgis>"))
        .filter(|(start, end)| start <= end)
        .map(|(start, end)| text[start..end].trim_matches('\n').to_string() + "\n");
    match body {
        Some(body) => Ok(Some(LayerStyle::Qml(body))),
        None => Err(IoError::invalid(
            &path,
            "not a QGIS style: no <qgis> element",
        )),
    }
}

/// How a layer of a project is drawn.
#[derive(Debug, Clone, PartialEq)]
pub enum LayerStyle {
    /// A style of timesift's.
    Style(RasterStyle),
    /// The body of a `.qml` file ([`read_qml`]).
    Qml(String),
}

impl LayerStyle {
    /// The elements a project's `<maplayer>` holds for it.
    fn body(&self) -> String {
        match self {
            LayerStyle::Style(style) => pipe_and_blend(style),
            LayerStyle::Qml(body) => body.clone(),
        }
    }
}

/// One raster of a project.
#[derive(Debug, Clone, PartialEq)]
pub struct ProjectLayer {
    /// Name shown in the layer panel.
    pub name: String,
    /// The raster, relative to the project file's folder (written with `/`).
    pub path: String,
    /// How it is drawn.
    pub style: LayerStyle,
    /// Extent `[xmin, ymin, xmax, ymax]` in the project's CRS.
    pub extent: [f64; 4],
    /// Drawn when the project opens.
    pub visible: bool,
}

/// A group of layers in the layer panel, the first layer drawn on top.
#[derive(Debug, Clone, PartialEq)]
pub struct ProjectGroup {
    /// Its name.
    pub name: String,
    /// Its layers, top first.
    pub layers: Vec<ProjectLayer>,
}

fn spatial_reference(crs: Crs) -> String {
    match crs.epsg() {
        Some(code) => format!(
            "<spatialrefsys><authid>EPSG:{code}</authid><srid>{code}</srid></spatialrefsys>"
        ),
        None => "<spatialrefsys/>".to_string(),
    }
}

/// The text of a `.qgs` project of the groups' rasters, in `crs`, opening on `extent`.
pub fn qgs(title: &str, crs: Crs, extent: [f64; 4], groups: &[ProjectGroup]) -> String {
    let srs = spatial_reference(crs);
    let mut tree = String::new();
    let mut layers = String::new();
    let mut order = String::new();
    let mut n = 0;
    for group in groups {
        let _ = writeln!(
            tree,
            "    <layer-tree-group name=\"{}\" checked=\"Qt::Checked\" expanded=\"1\">",
            escape(&group.name)
        );
        for layer in &group.layers {
            n += 1;
            let id = format!("timesift_layer_{n}");
            let checked = if layer.visible {
                "Qt::Checked"
            } else {
                "Qt::Unchecked"
            };
            let _ = writeln!(
                tree,
                "      <layer-tree-layer id=\"{id}\" name=\"{}\" source=\"./{}\" \
                 providerKey=\"gdal\" checked=\"{checked}\" expanded=\"0\"/>",
                escape(&layer.name),
                escape(&layer.path)
            );
            let _ = writeln!(order, "      <item>{id}</item>");
            let [xmin, ymin, xmax, ymax] = layer.extent;
            let _ = write!(
                layers,
                "    <maplayer type=\"raster\" hasScaleBasedVisibilityFlag=\"0\">\n      \
                 <extent><xmin>{xmin}</xmin><ymin>{ymin}</ymin><xmax>{xmax}</xmax>\
                 <ymax>{ymax}</ymax></extent>\n      <id>{id}</id>\n      \
                 <datasource>./{}</datasource>\n      <layername>{}</layername>\n      \
                 <srs>{srs}</srs>\n      <provider>gdal</provider>\n{}    </maplayer>\n",
                escape(&layer.path),
                escape(&layer.name),
                indent(&layer.style.body(), "    ")
            );
        }
        tree.push_str("    </layer-tree-group>\n");
    }
    let [xmin, ymin, xmax, ymax] = extent;
    format!(
        "<!DOCTYPE qgis PUBLIC 'http://mrcc.com/qgis.dtd' 'SYSTEM'>\n\
         <qgis projectname=\"{title}\" version=\"3.22.0\">\n  <homePath path=\"\"/>\n  \
         <title>{title}</title>\n  <projectCrs>{srs}</projectCrs>\n  \
         <layer-tree-group>\n{tree}    <custom-order enabled=\"0\">\n{order}    </custom-order>\n  \
         </layer-tree-group>\n  <mapcanvas name=\"theMapCanvas\" annotationsVisible=\"1\">\n    \
         <units>meters</units>\n    <extent><xmin>{xmin}</xmin><ymin>{ymin}</ymin>\
         <xmax>{xmax}</xmax><ymax>{ymax}</ymax></extent>\n    <destinationsrs>{srs}</destinationsrs>\n  \
         </mapcanvas>\n  <projectlayers>\n{layers}  </projectlayers>\n  <properties>\n    \
         <Paths><Absolute type=\"bool\">false</Absolute></Paths>\n  </properties>\n</qgis>\n",
        title = escape(title)
    )
}

fn indent(text: &str, by: &str) -> String {
    text.lines().map(|l| format!("{by}{l}\n")).collect()
}

/// Writes a `.qgs` project (see [`qgs`]).
pub fn write_qgs(
    path: &Path,
    title: &str,
    crs: Crs,
    extent: [f64; 4],
    groups: &[ProjectGroup],
) -> Result<(), IoError> {
    write_bytes_atomically(path, qgs(title, crs, extent, groups).as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_range_leaves_out_nodata_and_the_tails() {
        let mut values: Vec<f32> = (0..=100).map(|v| v as f32).collect();
        values.extend([-32767.0, f32::NAN, f32::INFINITY]);
        assert_eq!(percentile_range(&values, Some(-32767.0)), Some((2.0, 98.0)));
        assert_eq!(percentile_range(&[f32::NAN], None), None);
    }

    #[test]
    fn a_fitted_diverging_ramp_is_at_least_twice_its_transparent_band() {
        let flat = vec![0.01_f32; 50];
        let style = RasterStyle::diverging_fitted(&flat, None, Some(0.2));
        assert_eq!(
            style,
            RasterStyle::Diverging {
                limit: 0.4,
                transparent_within: Some(0.2)
            }
        );
        let mut spread: Vec<f32> = (-100..=100).map(|v| v as f32 / 10.0).collect();
        spread.push(-32767.0);
        let RasterStyle::Diverging { limit, .. } =
            RasterStyle::diverging_fitted(&spread, Some(-32767.0), Some(0.2))
        else {
            panic!("a diverging style");
        };
        assert!((limit - 9.8).abs() < 0.11, "{limit}");
    }

    #[test]
    fn a_dod_ramp_is_symmetric_and_leaves_the_lod_band_transparent() {
        let text = qml(&RasterStyle::Diverging {
            limit: 2.0,
            transparent_within: Some(0.18),
        });
        assert!(text.contains("classificationMin=\"-2\" classificationMax=\"2\""));
        assert!(text.contains("<item value=\"-2\" color=\"#2166ac\""));
        assert!(text.contains("<item value=\"0\" color=\"#f7f7f7\""));
        assert!(text.contains("<item value=\"2\" color=\"#b2182b\""));
        assert!(text.contains("min=\"-0.18\" max=\"0.18\" percentTransparent=\"100\""));
        assert!(text.contains("<blendMode>0</blendMode>"));
    }

    #[test]
    fn a_flat_raster_still_gets_a_ramp_and_a_hillshade_multiplies() {
        let text = qml(&RasterStyle::Terrain { min: 5.0, max: 5.0 });
        assert!(text.contains("minimumValue=\"4.5\" maximumValue=\"5.5\""));
        let text = qml(&RasterStyle::Terrain {
            min: f64::NAN,
            max: 3.0,
        });
        assert!(text.contains("minimumValue=\"0\" maximumValue=\"1\""));
        let shade = qml(&RasterStyle::Hillshade);
        assert!(shade.contains("type=\"hillshade\""));
        assert!(shade.contains(&format!("<blendMode>{BLEND_MULTIPLY}</blendMode>")));
    }

    /// A style written beside a raster reads back as the elements a project embeds for it; a
    /// file that is not a style is an error naming it.
    #[test]
    fn a_written_style_reads_back_as_the_project_embeds_it() {
        let dir = tempfile::tempdir().expect("tempdir");
        let raster = dir.path().join("dem.tif");
        assert_eq!(read_qml(&raster).expect("no file"), None);
        let style = RasterStyle::Terrain {
            min: 10.0,
            max: 20.0,
        };
        write_qml(&raster, &style).expect("written");
        let read = read_qml(&raster).expect("read").expect("a style");
        assert_eq!(read.body(), LayerStyle::Style(style).body());
        std::fs::write(raster.with_extension("qml"), "hello").expect("written");
        let err = read_qml(&raster).expect_err("not a style").to_string();
        assert!(err.contains("dem.qml") && err.contains("<qgis>"), "{err}");
    }

    #[test]
    fn a_project_lists_every_layer_once_in_its_group_with_escaped_names() {
        let layer = |name: &str, path: &str| ProjectLayer {
            name: name.into(),
            path: path.into(),
            style: LayerStyle::Style(RasterStyle::Rgb { alpha: true }),
            extent: [0.0, 0.0, 10.0, 20.0],
            visible: true,
        };
        let groups = [ProjectGroup {
            name: "A & B".into(),
            layers: vec![
                layer("ortho <1>", "epochs/a/ortho.tif"),
                layer("x", "x.tif"),
            ],
        }];
        let text = qgs("t", Crs::Epsg(32633), [0.0, 0.0, 10.0, 20.0], &groups);
        assert!(text.contains("name=\"A &amp; B\""));
        assert!(text.contains("<layername>ortho &lt;1&gt;</layername>"));
        assert_eq!(text.matches("<maplayer").count(), 2);
        assert_eq!(
            text.matches("<datasource>./epochs/a/ortho.tif</datasource>")
                .count(),
            1
        );
        assert!(text.contains("<authid>EPSG:32633</authid>"));
        assert!(text.contains("alphaBand=\"4\""));
    }
}
